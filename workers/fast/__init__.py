"""The fast (small-angle) renderer.

A frame's planes, the Wells spread, the target's gating and shadows, the stages of a
frame's light.
"""
