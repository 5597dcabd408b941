"""The wind estimator's C99 core (``include/bw_core.h``, ``src/``): the firmware as it is flashed, generated
from the same derivation as the Python reference (tools/derive_model.py). ``build`` compiles it for this
host; ``firmware_py.core_c`` is its Python binding; ``make -C firmware_c arm`` builds it for a Cortex-M4F."""
