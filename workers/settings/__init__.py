"""The scene's settings.

Frozen pydantic sections (sea, water, target, instrument, transport), the `Scene` that
validates them, and how a sample's random streams are keyed.
"""
