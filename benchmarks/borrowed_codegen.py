"""Does kernels._borrowed change the machine code of the compiled loops? (s12_tidy item 2)

Compiles ``verify.closed_loop._loop`` and ``plant.kernels.pzt_run`` anew as written and with ``_borrowed``
replaced by an inlined identity, a plain view (``arr[:]``) or a copy, and compares the final assembly with
the mangled names' uid taken out. Prints, per variant, the reference-count calls and atomics on a cycle of
its control-flow graph (tests/compiled_loops.py) and whether the code is the same as written.

Usage: OPENBLAS_NUM_THREADS=1 PYTHONPATH=. python benchmarks/borrowed_codegen.py   (~1-2 min: four fresh compiles of each)
"""
import json
import re
import types

import numba
import numpy as np

from tests.compiled_loops import refcounts_in_loops
from workbench.plant import PZTSimulator, load_plant
from workbench.plant import kernels as K
from workbench.verify import closed_loop as CL


@numba.njit(inline="always")
def _identity(arr):
    return arr


@numba.njit(inline="always")
def _slice(arr):
    return arr[:]


@numba.njit(inline="always")
def _copy(arr):
    return arr.copy()


VARIANTS = {"identity (the array itself)": _identity, "a plain view arr[:]": _slice, "a copy": _copy}


def _compile(dispatcher, sig, plain=None):
    """Final IR and assembly of ``dispatcher``'s function compiled anew; ``plain``: what replaces _borrowed."""
    func = dispatcher.py_func
    glb = dict(func.__globals__)
    if plain is not None:
        glb["_borrowed"] = plain                                     # pzt_run's own module
        plain_k = types.ModuleType("kernels_plain")                   # _loop's K._borrowed
        plain_k.__dict__.update({k: v for k, v in vars(K).items() if not k.startswith("__")})
        plain_k._borrowed = plain
        glb["K"] = plain_k
    fresh = numba.njit(error_model="numpy")(types.FunctionType(func.__code__, glb, func.__name__,
                                                                 func.__defaults__, func.__closure__))
    fresh.compile(sig)
    return fresh.inspect_llvm(sig), fresh.inspect_asm(sig)


def main():
    plant = load_plant("plants/p888_51_sn637_creep.toml")
    ctrl = CL.controller_from_json(json.loads(open("controllers/sn637_loopshape.json").read()))
    cl = CL.ClosedLoop(plant, ctrl, noise=True, seed=3)
    cl.reset(u0=50.0)
    cl.run(np.zeros(50))
    PZTSimulator(plant.pzt, 1e-6).run(np.full(10, 1.0))
    for name, disp, part in (("closed_loop._loop", CL._loop, "closed_loop5_loopB"),
                             ("kernels.pzt_run", K.pzt_run, "7pzt_runB")):
        sig = disp.signatures[0]
        strip = lambda s: re.sub(r"B\d+v\d+B", "B_uid_B", s)         # noqa: E731  the mangled names' counter
        ir_b, asm_b = _compile(disp, sig)
        n_blocks, n_cyclic, hits = refcounts_in_loops(ir_b, part)
        print(f"{name} as written (_borrowed): {n_blocks} blocks, {n_cyclic} on a cycle, {len(hits)} reference "
              f"counts/atomics on a cycle")
        for label, plain in VARIANTS.items():
            ir_p, asm_p = _compile(disp, sig, plain)
            n_blocks, n_cyclic, hits = refcounts_in_loops(ir_p, part)
            same = strip(asm_b) == strip(asm_p)
            print(f"  _borrowed -> {label}: {n_blocks} blocks, {n_cyclic} on a cycle, {len(hits)} reference "
                  f"counts/atomics on a cycle; machine code {'the same' if same else 'differs'}")
    print(f"numba {numba.__version__}")

if __name__ == "__main__":
    main()
