"""Flow as files and pictures: the OpenEXR flow (the shards' ground truth), Middlebury ``.flo``, and
colour-wheel pictures with their legend.
"""
