"""A creep + delay record drawn with its sensor delay's sign flipped (a leading sensor) through the tracing and
the file's core choice: the written delay, the development and test replays (review of s15_rt, fix 1).

Usage: ``OPENBLAS_NUM_THREADS=1 python benchmarks/round_trip_leading_delay.py SIZE SEED`` (10 kHz calibration
protocol; seeds >= 47 are reserved)."""
import sys, dataclasses, time
from pathlib import Path
sys.path.insert(0, str(Path(__file__).resolve().parent))
import calibrate_confusion as cc
from workbench.calibrate.synthetic import plant_with_effect, simulate_record, benchmark_protocol
from workbench.calibrate.splits import make_split
from workbench.calibrate.base_fit import fit_base
from workbench.calibrate.tracing import trace_effect
import workbench.calibrate.plant_update as pu
from workbench.plant import load_plant
PP = Path(__file__).resolve().parents[1] / "plants" / "p888_51_sn637.toml"; plant0 = load_plant(PP)
rate, proto, size, seed = 1e4, "calibration", float(sys.argv[1]), int(sys.argv[2])
t, v = benchmark_protocol(proto, rate, cc.ROWS[rate])
plant, truth = plant_with_effect(plant0, ("creep", "delay"), seed, duration_s=float(t[-1]), size=size)
d = plant.additions.sensor_delay_s
plant = dataclasses.replace(plant, additions=dataclasses.replace(plant.additions, sensor_delay_s=-d))
r = simulate_record(plant, t, v, seed=seed)
sp = make_split(t, r["voltage_v"], "blocks")
base = fit_base(cc._record(r, 1.0 / rate), plant0.pzt.series_resistance_ohm, train=sp.train, test=sp.test, pzt=plant.pzt, dac_range_v=plant.gauge.dac_range_v)
res = trace_effect(base, split=sp)
print("drawn delay", -d, "stages", [(s["effect"], s["channel"], s["parameters"].get("delay_s"), s["parameters"].get("scale")) for s in res["stages"]], "model", res["error_after"]["rms"], flush=True)
t0 = time.time()
core, dev, err = pu.choose_core(PP, plant0, base, res, Path("rec.csv"), sp.train, test=sp.test)
print("core", "refitted" if core["hysteresis"] is not None else "declared", "joint", core.get("joint"), "delay", core.get("sensor_delay_s"), core.get("delay_s"), "dev", dev, "test", err and err["rms"], "x model", err and err["rms"] / res["error_after"]["rms"], f"{time.time()-t0:.0f}s")
