"""Measuring registration: EPE metrics and buckets, the classical baselines, the closed-loop
compensation check, and ``projreg bench``'s run, methods and report.
"""
