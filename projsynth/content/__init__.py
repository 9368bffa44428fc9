"""What is projected and what it lands on: image folders (natural, generated) with their splits, and the
built-in procedural images.
"""
