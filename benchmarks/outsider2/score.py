"""s34_outsider: score logs/results.jsonl (from batch.py).

    python benchmarks/outsider2/score.py [logs/results.jsonl]

Classes: a clean record is wrong when a named effect (not none / inconclusive) comes back; a record with one
effect is right when `effect` is its name (batch.RIGHT), wrong when another name comes back (for an effect no
name fits -- hum, slew behind the monitor, quantization, glitches, a gain error -- any name is wrong); a pair is
right when both names are among the stages, wrong when a stage's name is neither. Sizes are batch.py's (x noise).
"""
import json
import math
import sys
from collections import Counter, defaultdict
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from batch import RIGHT  # noqa: E402

NOANS = ("none", "inconclusive")


def classify(d):
    effs = d["effects"]
    got = d.get("effect")
    names = [s[0] for s in d.get("stages") or []] or ([got] if got not in NOANS else [])
    if d["rc"] != 0 or got is None:
        return ("crash" if d.get("traceback") or d["rc"] not in (0, 2) else "refused"), None
    if not effs:
        return ("wrong" if got not in NOANS else "ok"), None
    want = {RIGHT[e["name"]] for e in effs} - {None}
    size = max(d["sizes"].values()) if d["sizes"] else None
    if any(n not in want for n in names):
        return "wrong", size
    if want and want <= set(names):
        return "right", size
    if want and names:
        return "part", size
    return ("miss" if want else "ok"), size


def main(path):
    rows = [json.loads(l) for l in Path(path).read_text().splitlines() if l.strip()]
    twin = {d["config"]: (d.get("effect"), d.get("channel")) for d in rows
            if d["name"] == d["config"] + "__clean" + "".join(d.get("args") and ["_blocks"] or [])}
    twin_ch = {d["config"]: d.get("channels") or {} for d in rows
               if d["name"] == d["config"] + "__clean" + "".join(d.get("args") and ["_blocks"] or [])}
    cnt = defaultdict(Counter)
    lines = []
    for d in rows:
        cls, size = classify(d)
        if cls in ("wrong", "right") and d["effects"] and twin.get(d["config"]) == (d.get("effect"), d.get("channel")):
            cls += "=twin"     # the same name on the same channel as the clean twin: the base's misfit, not the effect
        kind = "clean" if not d["effects"] else ("pair" if len(d["effects"]) > 1 else
                                                  ("named" if RIGHT[d["effects"][0]["name"]] else "no-name"))
        if d.get("args") and "--split" in d["args"] and "blocks" not in d["args"]:
            kind = "split"     # a clean record re-run under --split forward / cycles (batch_splits.log)
        elif "_seed" in d["name"]:
            kind = "seed"      # the same clean record with another noise draw
        elif "PIdensity" in d["name"] or "demag" in d["name"] or "nocurrent" in d["name"]:
            kind = "control"   # the generator moved toward the engine's family (density of r only / PI rest state)
        big = size is not None and size >= 3
        cnt[kind][cls + (" (>=3x)" if big and kind in ("named", "pair") else "")] += 1
        eb, ea = d.get("error_before"), d.get("error_after")
        ch = d.get("channels") or {}
        base = "; ".join(f"{k} {v['rms'] / v['noise_floor']:.0f}x floor, line/base {v['line'] / v['rms']:.2g}"
                         for k, v in ch.items() if v.get("rms") and v.get("noise_floor") and v.get("line"))
        flag = []
        # the benchmark's size: the excess of the base's held-out error over the clean twin's, in noise floors
        exc = {}
        for k, v in ch.items():
            tw = twin_ch.get(d["config"], {}).get(k)
            if d["effects"] and tw and v.get("rms") and tw.get("rms") and v.get("noise_floor") and k in d["sizes"]:
                exc[k] = round(math.sqrt(max(v["rms"] ** 2 - tw["rms"] ** 2, 0)) / v["noise_floor"], 1)
        if exc:
            flag.append(f"excess={exc}")
        if eb and ea and ea > 1.05 * eb:
            flag.append(f"AFTER>{ea / eb:.2g}xBEFORE")
        if d.get("traceback"):
            flag.append("TRACEBACK")
        lines.append(f"{cls:6s} {d['name']:36s} size={ {k: round(v, 1) for k, v in d['sizes'].items()} } -> "
                     f"{d.get('effect')} [{d.get('channel')}] {d.get('agreement')} stages={d.get('stages')} "
                     f"before={eb if eb is None else f'{eb:.3g}'} after={ea if ea is None else f'{ea:.3g}'} "
                     f"({d.get('error_after_source')}) warn={len(d.get('warnings') or [])} {' '.join(flag)} | {base}")
    print("\n".join(lines))
    print()
    for k, c in cnt.items():
        print(f"{k:8s} n={sum(c.values()):3d} " + ", ".join(f"{a}: {b}" for a, b in sorted(c.items())))
    print("total", len(rows), "(wrong=twin: the clean twin (same config, no effect) gives the same name and channel)")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else HERE / "logs" / "results.jsonl")
