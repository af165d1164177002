"""Finding 1's variants: the same clean 0.5 Hz triangle (2.5 kHz, 10 s) on other plant files, without noise,
and a sine of the same period and span, to see what the named resonance follows.

    PYTHONPATH=. OPENBLAS_NUM_THREADS=1 python benchmarks/outsider/triangle_variants.py
"""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
import harness  # noqa: E402
from harness import calibrate, sine, summary, triangle  # noqa: E402
from workbench.calibrate.synthetic import SensorNoise, plant_with_effect, simulate_record  # noqa: E402
from workbench.plant import load_plant  # noqa: E402

for name, plant_path, (t, v), kw in [
        ("flexure (no 70 kHz mode) tri", "plants/p888_51_sn637_on_flexure.toml", triangle(2.5e3, 10.0, 0.5), {}),
        ("sn637 tri, noise-free", "plants/p888_51_sn637.toml", triangle(2.5e3, 10.0, 0.5),
         dict(noise=SensorNoise(0, 0, 0), gauge_noise=False)),
        ("sn637 sine 0.5 Hz same span", "plants/p888_51_sn637.toml", sine(2.5e3, 10.0, 0.5), {}),
        ("sn637 tri, resistor 0 in plant+record", None, triangle(2.5e3, 10.0, 0.5), {}),
]:
    p0 = load_plant(plant_path or "plants/p888_51_sn637.toml")
    meta = None
    if plant_path is None:
        import dataclasses
        p0 = dataclasses.replace(p0, pzt=dataclasses.replace(p0.pzt, series_resistance_ohm=0.0))
        meta = {"series_resistor_ohm": 0}
        plant_path = "plants/p888_51_sn637.toml"
    pl, _ = plant_with_effect(p0, "none", 1)
    r = simulate_record(pl, t, v, seed=1, **kw)
    res = calibrate(r, plant_path, name.replace(" ", "_"), meta=meta)
    print(f"{name:<40}", summary(res), res.get("parameters"), flush=True)
