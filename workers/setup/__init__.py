"""A scene's setup, built once per scene and per frame.

The sea's cascades, the camera and laser geometry, the gates, the rays through the
interface, the sensor at a frame.
"""
