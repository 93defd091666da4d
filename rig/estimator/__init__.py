"""rig.estimator — the C estimator from Python: the ctypes binding of the native
library (`native`), the bias network in the C layout (`bias_net`) and where it was
trained (`trained_region`), replay of a recording in-process (`evaluate`), accuracy
against ground truth (`metrics`) and the onboard footprint for the Cortex-M4F
(`footprint`).

May import: `rig.data`.
"""
