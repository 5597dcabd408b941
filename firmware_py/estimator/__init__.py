"""The estimator: the portable unit that would run on the balloon's microcontroller.

Everything the filter computes per sample lives here, and only here: state layout and tuning
(``state``), the balloon model (``model``, ``generated``), the wind's process noise (``tuning``),
memory, prediction and fusion (``ekf``), the measurement rows (``measurements``), what to fuse when
(``control``) and the WIND_COV fields (``outputs``). It imports nothing but itself, ``math``, numpy
and the core's design, atmosphere and rotations (tests/unit/test_layers.py): no I/O, no MAVLink, and
no numpy allocation in the step (tests/unit/test_allocation.py). A port to C starts and ends here.
"""
