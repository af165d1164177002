"""s38_wrong: tally fresh.py JSON lines per tree: right / none / inconclusive / wrong / refused, and the records that
changed.  python benchmarks/logs/s38_wrong/tally.py FILE.jsonl [...]"""
import json
import sys
from collections import Counter, defaultdict

RIGHT = {"clean": None, "creep": "creep", "mode": "resonance", "delay": "delay"}
rows = [json.loads(l) for f in sys.argv[1:] for l in open(f) if l.strip()]
by = defaultdict(dict)
for d in rows:
    by[d["case"]["name"]][d["tree"].split("/")[-1]] = d


def cls(d):
    if d["rc"] != 0 or d.get("effect") is None:
        return "refused" if d["rc"] == 2 else "crash"
    names = [s.split("/")[0] if isinstance(s, str) else s[0] for s in d.get("stages") or []]
    want = RIGHT[d["case"]["kind"]]
    if not names:
        return d["effect"] if d["effect"] in ("none", "inconclusive") else "?"
    if any(n != want for n in names):
        return "wrong"
    return "right"


trees = sorted({t for v in by.values() for t in v})
tab = {t: defaultdict(Counter) for t in trees}
for name, v in by.items():
    for t, d in v.items():
        tab[t][d["case"]["kind"]][cls(d)] += 1
for t in trees:
    print(t, {k: dict(c) for k, c in tab[t].items()})
print("changed:")
for name, v in sorted(by.items()):
    a = {t: (cls(d), d.get("effect"), d.get("channel"), d.get("agreement")) for t, d in v.items()}
    if len({x[0:3] for x in a.values()}) > 1:
        print(" ", name, a)
print("wrong:")
for name, v in sorted(by.items()):
    for t, d in v.items():
        if cls(d) == "wrong":
            print(" ", t, name, d.get("effect"), d.get("channel"), d.get("agreement"), d.get("stages"))
