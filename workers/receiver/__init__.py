"""The receiver: the lidar equation's photon budget and the detector's shot noise."""
