"""Build the fuzz3 workspace (argument, e.g. /tmp/fz3/base): copies of the repo inputs and two MIMO controllers."""
import shutil, sys
from pathlib import Path
ROOT = Path(__file__).resolve().parents[2]
WS = Path(sys.argv[1])
if WS.exists():
    shutil.rmtree(WS)
WS.mkdir(parents=True)
for f in ("plants", "studies", "controllers"):
    shutil.copytree(ROOT / f, WS / f)
bad = WS / "bad"; bad.mkdir()
(bad / "a_file").write_text("x\n")
sys.path.insert(0, str(ROOT / "tests"))
from verify.mirror_cases import quick_design
from workbench.export.mimo import MimoController
from workbench.plant.mirror import load_mirror
fsm = load_mirror(WS / "plants" / "fsm_p888_51.toml")
d, _ = quick_design(fsm)
MimoController.from_design(d, fsm, name="mimo").write(WS / "controllers", "mimo")
d, _ = quick_design(fsm, iff=True)
MimoController.from_design(d, fsm, name="mimo_iff").write(WS / "controllers", "mimo_iff")
print("mimo written")
