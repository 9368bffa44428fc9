"""Datasets of rendered samples: the transform table, the plan (every sample a pure function of config,
seed and id), shards and their manifest, generation across workers and machines, verification,
export, and re-rendering a stored sample with any projector image.
"""
