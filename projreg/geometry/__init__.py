"""Geometry without weights: frames of different sizes, homographies (fitted, from SIFT + RANSAC,
densified), warps, image operations and smooth spline surfaces. Everything above builds on these.
"""
