"""The array backends a sample renders on.

numpy with the numba kernels, or PyTorch on CPU or CUDA; their kernels, and the
renderer's byte-bounded caches.
"""
