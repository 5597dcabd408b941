"""The winch profile against the simulator's truth (docs/estimator.md, "The winch"), several seeds:

    .venv/bin/python -m benchmarks.bench_profile [--scenario profile] [--seeds 1 2 3 4 5] [--jobs 2]
        [--dir DIR] [--json FILE]

Per seed: ``balloon-sim`` writes the tlog and the truth, ``balloon-gs reprocess`` the profile
(``<stem>_profile.nc``), then each leg's height bins are compared with the truth's wind at the balloon
averaged over the same leg in the same bins of the TRUE height. Metrics over all bins of all legs:
RMS speed error (m/s), RMS direction error (deg), RMS vector error (m/s), error / reported accuracy
(RMS of the u and v errors over their 1-sigma: honest = 1), the fitted power-law exponent and veer
against the truth's (0.14, 10 deg per 100 m for ``profile``), and their own error / sigma; in brackets
the same fits to the truth's own bins (what the turbulent atmosphere did on these legs: the part of
the exponent's error that is sampling, not the estimator)."""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
from multiprocessing import Pool

import numpy as np

from balloon_core import userargs
from balloon_core.atomic import atomic_open

PY = sys.executable


def run_seed(scenario: str, seed: int, outdir: str) -> dict:

    stem = os.path.join(outdir, f"{scenario}-{seed}")
    tlog, truth_csv = f"{stem}.tlog", f"{stem}.csv"
    if not os.path.exists(truth_csv):
        subprocess.run([PY, "-m", "sim_hil", "--scenario", scenario, "--duration", str(duration(scenario)),
                        "--seed", str(seed), "--out", tlog, "--truth", truth_csv, "--quiet"], check=True)  # fmt: skip
    cfg = f"{stem}.toml"
    with open(cfg, "w") as fh:
        fh.write(subprocess.run([PY, "-m", "sim_hil", "--scenario", scenario, "--print-config"], check=True,
                                capture_output=True, text=True).stdout)  # fmt: skip
    subprocess.run([PY, "-m", "ground_station", "reprocess", tlog, "--out", f"{stem}.nc", "--config", cfg,
                    "--plot", f"{stem}.png", "--quiet"], check=True, capture_output=True)  # fmt: skip
    return evaluate(stem, seed)


def evaluate(stem: str, seed: int) -> dict:
    """The metrics of one reprocessed flight (``<stem>_profile.nc``) against its truth (``<stem>.csv``)."""
    import xarray as xr

    from postflight.profile import QC_FEW_SAMPLES

    truth = np.genfromtxt(f"{stem}.csv", delimiter=",", names=True)
    ds = xr.open_dataset(f"{stem}_profile.nc", decode_times=False)
    z = ds["z"].values
    half = 0.5 * float(ds["z_bnds"].values[0, 1] - ds["z_bnds"].values[0, 0])
    t_clock = ds["leg_start"].values - ds["leg_start"].values  # sensor clock: no UTC in a simulated tlog
    errs = {"speed": [], "dir": [], "vec": [], "ratio": []}
    tz, tspeed, tdir, tsig = [], [], [], []  # the truth's own bins: what the atmosphere did on these legs
    sizes = ds["row_size"].values.astype(int)
    starts = np.r_[0, np.cumsum(sizes)[:-1]]
    qc = ds["qc_profile"].values.astype(int)
    for k in range(ds.sizes["profile"]):
        t0, t1 = float(ds["leg_start"][k] + t_clock[k]), float(ds["leg_end"][k] + t_clock[k])
        leg = (truth["time_s"] >= t0) & (truth["time_s"] <= t1)
        for j in range(starts[k], starts[k] + sizes[k]):
            zc = float(z[j])
            u, v = float(ds["eastward_wind"][j]), float(ds["northward_wind"][j])
            if not (math.isfinite(u) and math.isfinite(v)) or qc[j] & QC_FEW_SAMPLES:
                continue
            sel = leg & (np.abs(truth["height_m"] - zc) <= half)
            if sel.sum() < 20:
                continue
            tu, tv = truth["wind_e"][sel].mean(), truth["wind_n"][sel].mean()
            tz.append(zc)
            tspeed.append(math.hypot(tu, tv))
            tdir.append(math.degrees(math.atan2(-tu, -tv)) % 360.0)
            tsig.append((float(ds["wind_speed_uncertainty"][j]), float(ds["wind_from_direction_uncertainty"][j])))
            su, sv = float(ds["eastward_wind_uncertainty"][j]), float(ds["northward_wind_uncertainty"][j])
            errs["speed"].append(math.hypot(u, v) - math.hypot(tu, tv))
            d = math.degrees(math.atan2(-u, -v)) - math.degrees(math.atan2(-tu, -tv))
            errs["dir"].append((d + 180.0) % 360.0 - 180.0)
            errs["vec"].append(math.hypot(u - tu, v - tv))
            errs["ratio"] += [(u - tu) / su, (v - tv) / sv]
    rms = {k: float(np.sqrt(np.mean(np.square(v)))) for k, v in errs.items()}
    alpha, s_alpha = float(ds["power_law_exponent"]), float(ds["power_law_exponent_uncertainty"])
    veer, s_veer = float(ds["wind_veer"]), float(ds["wind_veer_uncertainty"])
    ds.close()
    t_alpha, t_veer = _truth_fit(np.array(tz), np.array(tspeed), np.array(tdir), np.array(tsig))
    return {"seed": seed, "bins": len(errs["vec"]), "rms_speed_mps": rms["speed"], "rms_dir_deg": rms["dir"],
            "truth_bins_alpha": t_alpha, "truth_bins_veer": t_veer,
            "rms_vector_mps": rms["vec"], "error_over_accuracy": rms["ratio"], "alpha": alpha,
            "sigma_alpha": s_alpha, "veer_deg_100m": veer, "sigma_veer": s_veer}  # fmt: skip


def _truth_fit(z: np.ndarray, speed: np.ndarray, direction: np.ndarray, sig: np.ndarray) -> tuple[float, float]:
    """The power law and the veer fitted to the truth's own bins with the weights the profile's fit
    gave the estimate's (its bins' sigmas)."""
    from postflight.profile import _fit_line

    if len(z) < 3:
        return math.nan, math.nan
    z_ref = float(np.exp(np.mean(np.log(z))))
    _, alpha, _ = _fit_line(np.log(z / z_ref), np.log(speed), sig[:, 0] / speed)
    rel = (direction - direction.mean() + 180.0) % 360.0 - 180.0
    _, veer, _ = _fit_line(z / 100.0, rel, sig[:, 1])
    return alpha, veer


def duration(scenario: str) -> float:
    from sim_hil.scenarios import SCENARIOS

    return SCENARIOS[scenario].winch.times_s[-1] + 5.0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="profile")
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4, 5])
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--dir", default="/tmp/bench_profile")
    ap.add_argument("--json")
    args = ap.parse_args(argv)
    try:  # the one rule for output options, before any flight is flown
        userargs.check_outputs({}, {"--json": args.json})
    except userargs.UserError as exc:
        raise SystemExit(userargs.fail("bench_profile", exc)) from None
    from sim_hil.scenarios import SCENARIOS

    sc = SCENARIOS[args.scenario]
    true_alpha, true_veer = sc.truth.shear_exponent, sc.truth.veer_deg_per_100m
    os.makedirs(args.dir, exist_ok=True)
    with Pool(args.jobs) as pool:
        rows = pool.starmap(run_seed, [(args.scenario, s, args.dir) for s in args.seeds])
    print(f"{args.scenario}: truth alpha {true_alpha}, veer {true_veer} deg / 100 m")
    print("seed bins  speed_rms dir_rms vec_rms err/acc  alpha (err, err/sigma) [truth bins]   veer (err) [truth bins]")
    for r in rows:
        da, dv = r["alpha"] - true_alpha, r["veer_deg_100m"] - true_veer
        za, zv = da / r["sigma_alpha"], dv / r["sigma_veer"]
        print(f"{r['seed']:4d} {r['bins']:4d}  {r['rms_speed_mps']:8.3f} {r['rms_dir_deg']:7.2f} "
              f"{r['rms_vector_mps']:7.3f} {r['error_over_accuracy']:7.2f}  {r['alpha']:.3f} ({da:+.3f}, "
              f"{za:+.1f}) [{r['truth_bins_alpha']:.3f}]  {r['veer_deg_100m']:+6.1f} ({dv:+.1f}, {zv:+.1f}) "
              f"[{r['truth_bins_veer']:+.1f}]")  # fmt: skip
    if args.json:
        with atomic_open(args.json) as fh:
            json.dump(rows, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
