"""``make arm``: the C core on a Cortex-M4F, under QEMU (docs/porting.md).

Cross-compiles the core and its replay program for the mps2-an386 board (arm-none-eabi-gcc, Cortex-M4F,
hard float), replays a recorded flight (the frozen paper-reference capture, through the firmware's input
pipeline) on it under ``qemu-system-arm -icount shift=0`` (one instruction per virtual nanosecond, so the
board's 25 MHz SysTick counts 40 instructions a tick), holds its outputs against the host's float build
of the same program, and reports the instructions per filter step (median and worst), the core's flash
(text + data of its objects) and its RAM (the estimator struct plus the deepest stack of a step).
Ends with the one line ``cortex-m4: N instructions per step (median), M worst; flash F B, ram R B``.
Without the cross tools: one line saying so, exit 0 (CI installs them best effort).
"""

from __future__ import annotations

import gzip
import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CORE = ROOT / "firmware_c"
BUILD = CORE / "build"
FLIGHT = ROOT / "tests" / "data" / "golden" / "paper-reference.tlog.gz"
REPORT = BUILD / "arm" / "report.json"
TOOLS = ("arm-none-eabi-gcc", "arm-none-eabi-size", "qemu-system-arm")


def qemu(elf: Path, stream: Path, out: Path, stats: Path) -> None:
    args = ",".join(f"arg={a}" for a in ("replay", stream.name, out.name, stats.name))
    cmd = ["qemu-system-arm", "-M", "mps2-an386", "-nographic", "-monitor", "none", "-serial", "none", "-icount",
           "shift=0", "-semihosting-config", f"enable=on,target=native,{args}", "-kernel", str(elf)]  # fmt: skip
    subprocess.run(cmd, check=True, cwd=stream.parent, timeout=600)


def core_sizes() -> tuple[int, int]:
    """(flash, static RAM) of the core's own objects: text + data, data + bss."""
    r = subprocess.run(["arm-none-eabi-size", "-t", str(BUILD / "arm" / "core.a")], capture_output=True, text=True,
                       check=True)  # fmt: skip
    text, data, bss = (int(v) for v in r.stdout.strip().splitlines()[-1].split()[:3])
    return text + data, data + bss


def main() -> int:
    missing = [t for t in TOOLS if shutil.which(t) is None]
    if missing:
        print(f"cortex-m4: skipped ({', '.join(missing)} not installed; apt install gcc-arm-none-eabi "
              "libnewlib-arm-none-eabi qemu-system-arm)")  # fmt: skip
        return 0
    sys.path.insert(0, str(ROOT))
    from balloon_core.config import Design
    from firmware_py import lockstep
    from firmware_py.estimator.state import FilterConfig

    subprocess.run(["make", "-s", "-C", str(CORE), "arm-elf", "replay"], check=True)
    with tempfile.TemporaryDirectory() as t:
        tmp = Path(t)
        flight = tmp / "flight.tlog"
        flight.write_bytes(gzip.decompress(FLIGHT.read_bytes()))
        samples, cfg = lockstep.flight_samples(str(flight), FilterConfig(float32=True))
        lockstep.write_stream(str(tmp / "stream.bin"), Design(), cfg, samples)
        qemu(BUILD / "arm" / "replay.elf", tmp / "stream.bin", tmp / "arm.bin", tmp / "stats.txt")
        subprocess.run([str(BUILD / "replay_float"), str(tmp / "stream.bin"), str(tmp / "host.bin")], check=True)
        equal, line = lockstep.compare_outputs(lockstep.read_outputs(str(tmp / "arm.bin")),
                                               lockstep.read_outputs(str(tmp / "host.bin")))  # fmt: skip
        words = (tmp / "stats.txt").read_text().split()
        stats = {words[i]: int(words[i + 1]) for i in range(0, len(words), 2)}
    flash, static = core_sizes()
    ram = stats["estimator_bytes"] + stats["stack_bytes"] + static
    report = {"flight": FLIGHT.name, "steps": stats["steps"], "median_instructions": stats["median_instructions"],
              "worst_instructions": stats["worst_instructions"], "flash_bytes": flash, "ram_bytes": ram,
              "estimator_bytes": stats["estimator_bytes"], "stack_bytes": stats["stack_bytes"],
              "equal_to_host": equal, "comparison": line}  # fmt: skip
    REPORT.write_text(json.dumps(report, indent=1) + "\n")
    print(f"cortex-m4 against the host float build: {line}")
    print(f"cortex-m4: {stats['median_instructions']} instructions per step (median), {stats['worst_instructions']} "
          f"worst; flash {flash} B, ram {ram} B")  # fmt: skip
    return 0 if equal else 1


if __name__ == "__main__":
    sys.exit(main())
