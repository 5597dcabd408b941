"""The estimator: the portable unit that would run on the balloon's microcontroller.

Everything the filter computes per sample lives here, and only here: state layout and tuning
(``state``), the balloon model (``model``, ``generated``), the wind's process noise (``tuning``),
memory, prediction, fusion and the one reset API (``ekf``), the internal tunables (``params``), one
module per aid source with its control beside its fusion (``aid_sources``), the step (``control``)
and the WIND_COV fields (``outputs``). It imports nothing but itself, ``math``, numpy
and the core's design, atmosphere and rotations (tests/unit/test_layers.py): no I/O, no MAVLink, and
no numpy allocation in the step (tests/unit/test_allocation.py). A port to C starts and ends here.
"""
