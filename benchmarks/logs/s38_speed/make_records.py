"""Write the protocol records (effects none/creep/resonance/delay/drift, seed 100 as calibrate_speed_pairs does)."""
import sys
from pathlib import Path
ROOT = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(ROOT))
from workbench.calibrate.protocol import calibration_protocol
from workbench.calibrate.synthetic import plant_with_effect, simulate_record, write_record
from workbench.plant import load_plant
out = Path(sys.argv[1]); out.mkdir(parents=True, exist_ok=True)
base = load_plant(ROOT / "plants" / "p888_51_sn637.toml")
t, v = calibration_protocol()
for effect in sys.argv[2:] or ["none", "creep", "resonance", "delay", "drift"]:
    plant, _ = plant_with_effect(base, effect, 100)
    write_record(out / f"{effect}.csv", simulate_record(plant, t, v, seed=100))
    print(effect)
