"""The simulated projector-camera rig: lenses, surfaces, the scene's ray casts (exact forward and
backward maps), rig poses, motion of a flying projector, the photometric models and the renderer.
"""
