"""The geometric refinement after the network: its configuration, the refiner (hypotheses, candidates,
selection, growth), the evidence it checks and the per-pixel confidence of its answer.
"""
