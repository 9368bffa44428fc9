"""Shared plumbing with no knowledge of scenes or datasets: the console (help, one-line errors,
progress), cores, numba kernels' settings, files written whole, image files, parameter ranges, guards
against writing over inputs, and silencing native decoders.
"""
