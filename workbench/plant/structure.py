"""M(.) of seed 000 Fig. 3 as a structure: the stacks' mechanical side, coupled both ways.

Fig. 3 feeds the force F_e + T_em V_p into the mechanical impedance M(.) and takes the
stack's elongation x back to eq. 9, V_p = (q - T_em x) / C_p; "M(.) can be as simple as a
spring representing the mechanical stiffness of the PZT material or a FEM of the structure
the PZT is embedded into". :class:`Structure` is that M(.) for one or several stacks:

* inputs: for each stack the pair of forces at its two ends that pushes them apart
  (F_p + F_e of Fig. 3, N), then any further external forces (N);
* outputs: for each stack its elongation x (m), then its elongation rate (m/s), then any
  further outputs (mirror angles, ...);
* the stack's own stiffness k_p is part of M (Fig. 3: M = 1/k_p for a free stack), so the
  static stiffness at a stack is at least its k_p.

It is held as a continuous python-control ``StateSpace`` (``Structure.ss``). The feedthrough
from a stack's force to its own elongation is the residual (static-correction) compliance
r = 1/k_static - sum_i psi_i^2 / (m_i w_i^2): the compliance of everything the states do not
resolve (for the bare spring, all of it: r = 1/k_p and no states). The coupled kernel
(:mod:`workbench.plant.coupled`) eliminates it exactly, as today's kernel eliminates 1/k_p,
so residuals must be per stack (diagonal): stacks interact through the states only.

Constructors: :func:`spring` (M = 1/k_p), :func:`mode_filter` (today's unit-DC-gain mode
cascade as a structure), :func:`modal_structure` (frequencies, damping ratios, modal masses,
participation at each stack's two ends, static stiffness), :func:`load_state_space`
(``.npz``/``.mat`` with A, B, C, D), :func:`structure_from_section` (the plant file's
``[structure]`` section).
"""

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import DataFileError, PlantDefinitionError

__all__ = ["Structure", "spring", "mode_filter", "modal_structure", "load_state_space",
           "structure_from_section", "STRUCTURE_SCHEMA"]


@dataclass(frozen=True)
class Structure:
    """The mechanical side M(.) as a continuous state-space system (SI).

    Parameters
    ----------
    a, b, c, d : ndarray of float
        Continuous-time matrices. Inputs: ``n_stacks`` stack forces (N, pushing each stack's
        ends apart), then external forces (N). Outputs: ``n_stacks`` elongations (m),
        ``n_stacks`` elongation rates (m/s), then other outputs.
    n_stacks : int
        Number of stacks attached.
    output_names : tuple of str
        Names of the other outputs (after the elongations and rates).
    modal : dict or None
        For modal structures: ``freqs_hz``, ``damping_ratios``, ``modal_masses_kg`` and
        ``psi`` (modes x stacks, elongation participation); the states are then
        (eta_i, deta_i/dt) pairs and the stored energy and damping loss are known
        (:meth:`stored_energy_j`, :meth:`damping_power_w`).
    """

    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    d: np.ndarray
    n_stacks: int
    output_names: tuple = ()
    modal: dict | None = None

    def __post_init__(self):
        a, b, c, d = (np.atleast_2d(np.asarray(m, float)) for m in (self.a, self.b, self.c, self.d))
        n = a.shape[0] if a.size else 0
        a = a.reshape(n, n)
        b = b.reshape(n, -1) if n else np.asarray(self.b, float).reshape(0, d.shape[1])
        c = c.reshape(-1, n) if n else np.zeros((d.shape[0], 0))
        for name, v in (("a", a), ("b", b), ("c", c), ("d", d)):
            object.__setattr__(self, name, v)
            if not np.all(np.isfinite(v)):
                raise ValueError(f"structure matrix {name} has non-finite entries")
        ns = int(self.n_stacks)
        if ns < 1:
            raise ValueError(f"a structure needs at least one stack; got n_stacks = {ns}")
        if b.shape[1] != d.shape[1] or c.shape[0] != d.shape[0]:
            raise ValueError(f"inconsistent shapes: A {a.shape}, B {b.shape}, C {c.shape}, D {d.shape}")
        if d.shape[1] < ns or d.shape[0] < 2 * ns:
            raise ValueError(f"{ns} stack(s) need >= {ns} inputs and >= {2 * ns} outputs "
                             f"(elongations, then rates); got {d.shape[1]} inputs, {d.shape[0]} outputs")
        if d.shape[0] - 2 * ns != len(self.output_names):
            object.__setattr__(self, "output_names",
                               tuple(f"y{i}" for i in range(d.shape[0] - 2 * ns)))
        r = d[:ns, :ns]
        if np.any(np.abs(r - np.diag(np.diag(r))) > 1e-12 * max(np.abs(r).max(), 1e-300)):
            raise ValueError("the residual compliance between stacks (D[:n, :n]) must be diagonal: "
                             "stacks may interact through the structure's states only")
        if np.any(np.diag(r) < 0):
            raise ValueError(f"residual compliances must be >= 0 m/N; got {np.diag(r).tolist()}")
        if np.any(d[ns:2 * ns] != 0):
            raise ValueError("elongation rates cannot feed through from forces (D rows of the rates "
                             "must be zero): a massless damper is not a structure")
        if n and np.any(np.linalg.eigvals(a).real > 1e-9 * max(1.0, np.abs(a).max())):
            raise ValueError("the structure is unstable (an eigenvalue of A in the right half-plane)")

    # -- views ---------------------------------------------------------------------------
    @property
    def n_states(self):
        return self.a.shape[0]

    @property
    def n_external(self):
        """Number of external force inputs after the stack forces."""
        return self.d.shape[1] - self.n_stacks

    @property
    def residual_compliance_m_per_n(self):
        """Each stack's residual compliance r_j (the static correction), m/N."""
        return np.diag(self.d[:self.n_stacks, :self.n_stacks]).copy()

    @property
    def ss(self):
        """The structure as a python-control StateSpace (inputs and outputs named)."""
        ns = self.n_stacks
        inputs = [f"F_stack{j}" for j in range(ns)] + [f"F_ext{k}" for k in range(self.n_external)]
        outputs = ([f"x_stack{j}" for j in range(ns)] + [f"xdot_stack{j}" for j in range(ns)]
                   + list(self.output_names))
        import control          # (on first use: python-control costs ~1.5 s to import)
        return control.ss(self.a, self.b, self.c, self.d, inputs=inputs, outputs=outputs)

    def static_compliance_m_per_n(self):
        """Stack elongation per stack force at DC (ns x ns), m/N."""
        ns = self.n_stacks
        dc = self.d[:ns, :ns].copy()
        if self.n_states:
            dc -= self.c[:ns] @ np.linalg.solve(self.a, self.b[:, :ns])
        return dc

    def stored_energy_j(self, states, stack_forces_n):
        """Kinetic + strain energy of a modal structure, J (rows: samples).

        Parameters
        ----------
        states : ndarray, shape (n_samples, n_states)
        stack_forces_n : ndarray, shape (n_samples, n_stacks)
            The force on each stack's ends (it strains the residual compliance: r F^2 / 2).
        """
        if self.modal is None:
            raise ValueError("stored energy is known for modal structures only")
        m = self.modal["modal_masses_kg"]
        w = 2 * np.pi * self.modal["freqs_hz"]
        s = np.asarray(states, float)
        e = 0.5 * (s[:, 1::2] ** 2 + (w * s[:, 0::2]) ** 2) @ m
        f = np.asarray(stack_forces_n, float)
        return e + 0.5 * (f * f) @ self.residual_compliance_m_per_n

    def damping_power_w(self, states):
        """Power the modal damping dissipates, W (rows: samples)."""
        if self.modal is None:
            raise ValueError("damping loss is known for modal structures only")
        m = self.modal["modal_masses_kg"]
        w = 2 * np.pi * self.modal["freqs_hz"]
        z = self.modal["damping_ratios"]
        v = np.asarray(states, float)[:, 1::2]
        return (v * v) @ (2 * z * w * m)


def spring(stiffness_n_per_m):
    """M = 1/k_p: the free stack of Fig. 3 (no states, all compliance residual)."""
    k = float(stiffness_n_per_m)
    if not k > 0:
        raise ValueError(f"stiffness must be positive; got {k}")
    return Structure(np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((2, 0)), np.array([[1.0 / k], [0.0]]), 1)


def mode_filter(stiffness_n_per_m, modes):
    """Today's modes as a structure: M(s) = (1/k_p) prod_i w_i^2 / (s^2 + 2 z_i w_i s + w_i^2).

    The cascade the existing kernel applies to the quasi-static displacement, realized as a
    force -> elongation system (states: a chain of second-order sections, no residual). In
    the coupled kernel the modal motion also feeds eq. 9 back; today's kernel leaves that out.
    """
    if not modes:
        return spring(stiffness_n_per_m)
    import control
    k = float(stiffness_n_per_m)
    sys = control.tf([1.0 / k], [1.0])
    for md in modes:
        w = 2 * np.pi * md.freq_hz
        sys = sys * control.tf([w * w], [1.0, 2 * md.damping_ratio * w, w * w])
    g = control.ss(sys)
    # rate output: C A x (+ C B u, zero for a strictly proper section of relative degree >= 2)
    c_rate = g.C @ g.A
    if np.any(np.abs(g.C @ g.B) > 0):
        raise ValueError("mode cascade must have relative degree >= 2")
    return Structure(g.A, g.B, np.vstack([g.C, c_rate]), np.zeros((2, 1)), 1)


def modal_structure(freqs_hz, damping_ratios, modal_masses_kg, participation_end_a, participation_end_b,
                    static_stiffness_n_per_m, *, input_participation=None, output_participation=None,
                    output_names=()):
    """A modal model of M(.) with its static correction.

    Parameters
    ----------
    freqs_hz, damping_ratios, modal_masses_kg : array_like of float, shape (n_modes,)
        Modal frequencies (Hz, > 0), damping ratios (0 < zeta <= 1) and modal masses (kg)
        of the structure with the stacks' mechanical stiffness in it and F_p = 0.
    participation_end_a, participation_end_b : array_like, shape (n_modes, n_stacks)
        Mode shape at each stack's two ends along the stack's axis (dimensionless, with the
        modal mass scaling); the stack's elongation participates with psi = phi_b - phi_a.
        A 1-D array is read as one stack.
    static_stiffness_n_per_m : array_like of float, shape (n_stacks,)
        Force per elongation at each stack at DC, N/m (>= the stack's k_p: M holds the stack).
    input_participation : array_like, shape (n_modes, n_ext), optional
        Mode shape at further force inputs (external forces after the stack forces; a
        disturbance torque with the shape in rad per modal coordinate).
    output_participation : array_like, shape (n_modes, n_out), optional
        Further outputs as modal sums (e.g. a mirror angle per modal coordinate).

    Returns
    -------
    Structure
        States (eta_i, deta_i/dt) per mode; residual r_j = 1/k_j - sum_i psi_ij^2/(m_i w_i^2).
    """
    f = np.atleast_1d(np.asarray(freqs_hz, float))
    z = np.atleast_1d(np.asarray(damping_ratios, float))
    m = np.atleast_1d(np.asarray(modal_masses_kg, float))
    pa = np.asarray(participation_end_a, float)
    pb = np.asarray(participation_end_b, float)
    if pa.ndim == 1:
        pa, pb = pa[:, None], pb[:, None]
    nm = f.size
    if not (z.shape == m.shape == (nm,) and pa.shape == pb.shape and pa.shape[0] == nm):
        raise ValueError(f"one frequency, damping ratio, modal mass and participation row per mode; got "
                         f"{f.shape}, {z.shape}, {m.shape}, {pa.shape}, {pb.shape}")
    if np.any(f <= 0) or np.any((z <= 0) | (z > 1)) or np.any(m <= 0):
        raise ValueError("modal frequencies and masses must be > 0 and damping ratios in (0, 1]")
    ns = pa.shape[1]
    k = np.broadcast_to(np.asarray(static_stiffness_n_per_m, float), (ns,)).copy()
    if np.any(k <= 0):
        raise ValueError(f"static stiffness must be > 0 N/m; got {k.tolist()}")
    psi = pb - pa
    w = 2 * np.pi * f
    resid = 1.0 / k - (psi ** 2 / (m * w * w)[:, None]).sum(axis=0)
    if np.any(resid < -1e-9 / k):
        raise ValueError(f"the modes hold more compliance than the static stiffness allows at stack(s) "
                         f"{np.flatnonzero(resid < 0).tolist()}: sum psi^2/(m w^2) exceeds 1/k_static "
                         f"(residual {resid.tolist()} m/N); raise the modal masses or the stiffness")
    resid = np.maximum(resid, 0.0)
    po = np.zeros((nm, 0)) if output_participation is None else np.asarray(output_participation, float)
    if po.ndim == 1:
        po = po[:, None]
    pi = np.zeros((nm, 0)) if input_participation is None else np.asarray(input_participation, float)
    if pi.ndim == 1:
        pi = pi[:, None]
    if pi.shape[0] != nm or po.shape[0] != nm:
        raise ValueError(f"input and output participation need one row per mode ({nm}); got {pi.shape}, {po.shape}")
    n = 2 * nm
    a = np.zeros((n, n))
    b = np.zeros((n, ns + pi.shape[1]))
    for i in range(nm):
        a[2 * i, 2 * i + 1] = 1.0
        a[2 * i + 1, 2 * i] = -w[i] ** 2
        a[2 * i + 1, 2 * i + 1] = -2 * z[i] * w[i]
        b[2 * i + 1, :ns] = psi[i] / m[i]
        b[2 * i + 1, ns:] = pi[i] / m[i]
    c = np.zeros((2 * ns + po.shape[1], n))
    c[:ns, 0::2] = psi.T
    c[ns:2 * ns, 1::2] = psi.T
    c[2 * ns:, 0::2] = po.T
    d = np.zeros((c.shape[0], b.shape[1]))
    d[:ns, :ns] = np.diag(resid)
    modal = {"freqs_hz": f, "damping_ratios": z, "modal_masses_kg": m, "psi": psi}
    return Structure(a, b, c, d, ns, tuple(output_names), modal)


def load_state_space(path, n_stacks=1):
    """A structure from ``.npz`` or ``.mat`` holding A, B, C, D (continuous, SI).

    Inputs and outputs follow :class:`Structure`: stack forces first, then external forces;
    elongations, then elongation rates, then other outputs.
    """
    path = Path(path)
    try:
        if path.suffix == ".npz":
            with np.load(path) as f:
                mats = {k: np.asarray(f[k], float) for k in f.files}
        elif path.suffix == ".mat":
            import scipy.io
            mats = {k: np.asarray(v, float) for k, v in scipy.io.loadmat(path).items() if not k.startswith("__")}
        else:
            raise DataFileError(f"{path}: a state-space structure must be a .npz or .mat file")
    except (OSError, ValueError) as err:
        if isinstance(err, DataFileError):
            raise
        raise DataFileError(f"{path}: cannot be read as a state-space structure ({err})") from err
    missing = [k for k in "ABCD" if k not in mats]
    if missing:
        raise DataFileError(f"{path}: missing matrices {missing}; expected arrays A, B, C, D "
                            f"(continuous time, inputs: stack forces then external forces)")
    try:
        return Structure(mats["A"], mats["B"], mats["C"], mats["D"], n_stacks)
    except ValueError as err:
        raise DataFileError(f"{path}: {err}") from err


# Keys of the plant file's [structure] section (one stack: the plant file describes one).
STRUCTURE_SCHEMA = {
    "freqs_hz": ("floats", 0.0, 1e8, True, "modal frequencies in Hz, one per mode"),
    "damping_ratios": ("floats", 0.0, 1.0, True, "damping ratios in (0, 1], one per mode"),
    "modal_masses_kg": ("floats", 0.0, 1e6, True, "modal masses in kg, one per mode"),
    "participation_end_a": ("floats", -1e6, 1e6, False, "mode shape at the stack's grounded/first end, one per mode"),
    "participation_end_b": ("floats", -1e6, 1e6, False, "mode shape at the stack's second end, one per mode"),
    "static_stiffness_n_per_m": ("float", 0.0, 1e13, True, "force per elongation at DC in N/m, >= k_p"),
    "state_space_file": ("str", None, None, False, "a .npz/.mat file with A, B, C, D, relative to the plant file"),
}


def structure_from_section(path, section, stiffness_n_per_m):
    """Build the structure of a plant file's checked ``[structure]`` table.

    Either a modal model (``freqs_hz``, ``damping_ratios``, ``modal_masses_kg``,
    ``participation_end_a``, ``participation_end_b``, ``static_stiffness_n_per_m``) or
    ``state_space_file``. Errors name the file and the key.
    """
    path = Path(path)
    if "state_space_file" in section:
        extra = sorted(set(section) - {"state_space_file"})
        if extra:
            raise PlantDefinitionError(path, "structure", f"give either state_space_file or the modal keys, "
                                       f"not both (also found {extra})")
        try:
            st = load_state_space(path.parent / section["state_space_file"])
        except DataFileError as err:
            raise PlantDefinitionError(path, "structure.state_space_file", str(err)) from err
    else:
        keys = ("freqs_hz", "damping_ratios", "modal_masses_kg", "participation_end_a",
                "participation_end_b", "static_stiffness_n_per_m")
        for key in keys:
            if key not in section:
                raise PlantDefinitionError(path, f"structure.{key}", f"missing; expected {STRUCTURE_SCHEMA[key][4]}")
        n = section["freqs_hz"].size
        for key in keys[1:5]:
            if section[key].size != n:
                raise PlantDefinitionError(path, f"structure.{key}", f"has {section[key].size} entries; "
                                           f"expected {n}, one per mode in freqs_hz")
        try:
            st = modal_structure(section["freqs_hz"], section["damping_ratios"], section["modal_masses_kg"],
                                 section["participation_end_a"], section["participation_end_b"],
                                 section["static_stiffness_n_per_m"])
        except ValueError as err:
            raise PlantDefinitionError(path, "structure", str(err)) from err
    k_static = 1.0 / st.static_compliance_m_per_n()[0, 0]
    if k_static < stiffness_n_per_m * (1 - 1e-9):
        raise PlantDefinitionError(path, "structure", f"static stiffness {k_static:.6g} N/m is below the "
                                   f"stack's k_p = {stiffness_n_per_m:.6g} N/m; M(.) holds the stack's own "
                                   f"spring, so its static stiffness must be at least k_p")
    return st
