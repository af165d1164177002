"""What the compiled code of a numba function does inside its loops: reference counts and atomics.

A test helper (no workbench code): the final LLVM IR of one specialization, split into basic blocks, its
control-flow graph from the terminators' ``label %target`` operands, and the blocks that lie on a cycle
(a strongly connected component of more than one block, or a block that branches to itself). Whatever
runs per iteration of any loop runs in those blocks.
"""

import re
import types

import numba

_LABEL = re.compile(r'^(?:"([^"]+)"|([-\w.$]+)):')
_TARGET = re.compile(r'label %(?:"([^"]+)"|([-\w.$]+))')
_REFCOUNT = ("@NRT_incref", "@NRT_decref", "atomicrmw", "cmpxchg")


def fresh_llvm(dispatcher, signature, globals_=None, **options):
    """The final LLVM IR of ``dispatcher``'s Python function compiled anew for ``signature``.

    A new dispatcher without a cache: numba refuses to show the code of a specialization it loaded
    from its on-disk cache (it warns and returns an empty text). ``globals_``: names of the function's
    module replaced for this compilation (``{"_borrowed": a_plain_view}``), the module itself untouched.
    """
    func = dispatcher.py_func
    if globals_:
        func = types.FunctionType(func.__code__, {**func.__globals__, **globals_}, func.__name__,
                                  func.__defaults__, func.__closure__)
    fresh = numba.njit(**options)(func)
    fresh.compile(signature)
    return fresh.inspect_llvm(signature)


def _body(ir, name_part):
    lines = ir.splitlines()
    for i, line in enumerate(lines):
        if line.startswith("define") and name_part in line and "cpython" not in line:
            j = lines.index("}", i)
            return lines[i + 1:j]
    raise LookupError(f"no function whose name holds {name_part!r} in the IR")


def _blocks_on_cycles(body):
    blocks, order, cur = {"<entry>": []}, ["<entry>"], "<entry>"
    for line in body:
        m = _LABEL.match(line)
        if m:
            cur = m.group(1) or m.group(2)
            blocks[cur] = []
            order.append(cur)
        else:
            blocks[cur].append(line)
    succ = {b: {m.group(1) or m.group(2) for line in text for m in _TARGET.finditer(line)}
            for b, text in blocks.items()}
    index, low, on_stack, stack, comp, n = {}, {}, set(), [], {}, 0
    for root in order:                               # Tarjan's strongly connected components, iteratively
        if root in index:
            continue
        index[root] = low[root] = n
        n += 1
        stack.append(root)
        on_stack.add(root)
        work = [(root, iter(succ[root]))]
        while work:
            v, it = work[-1]
            for w in it:
                if w not in index:
                    index[w] = low[w] = n
                    n += 1
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(succ[w])))
                    break
                if w in on_stack:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    scc = []
                    while not scc or scc[-1] != v:
                        scc.append(stack.pop())
                        on_stack.discard(scc[-1])
                    for w in scc:
                        comp[w] = scc
    return blocks, {b for b in blocks if len(comp[b]) > 1 or b in succ[b]}


def refcounts_in_loops(ir, name_part):
    """(blocks, blocks on a cycle, the reference-count calls and atomics found on a cycle) of one function.

    ``name_part``: a piece of the function's mangled name (``"5_loop"``); its CPython wrapper is skipped.
    """
    blocks, cyclic = _blocks_on_cycles(_body(ir, name_part))
    hits = [line.strip() for b in cyclic for line in blocks[b] if any(r in line for r in _REFCOUNT)]
    return len(blocks), len(cyclic), hits
