"""Optics of the sea and the water.

Fresnel and Snell at the interface, the water's inherent optical properties, phase
functions, the Wells small-angle MTF.
"""
