"""The sea's surface.

Wave spectra, the multi-scale cascades, FFT synthesis of realisations, conditioning on
measured elevations.
"""
