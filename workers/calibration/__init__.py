"""The fast renderer calibrated by photon transport: a wing above both renderers.

Where Wells' small-angle theory misplaces the water's return (water that scatters many
times, the paper's phase function), the gates take transport's gains, tabulated once per
water by the Monte Carlo renderer (`workers.calibration.timegains`).
"""
