"""Ground truth for real rigs: structured-light pattern sets, the virtual rig that photographs them,
their sub-pixel decoding, and datasets of captured pairs.
"""
