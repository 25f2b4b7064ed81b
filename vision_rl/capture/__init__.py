"""Frame sources plus target sources written to the capture HDF5 file.

The file format lives in :mod:`vision_rl.capture.h5format` (numpy and h5py only; torch stays out of this layer).
"""
