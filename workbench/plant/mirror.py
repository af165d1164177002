"""The three-stack tip/tilt/piston fast steering mirror (issue 15, item 2).

Three stacks stand on a housing at angles theta_j on a radius r. Each pushes, through a lever
flexure of amplification a, the mirror at the point p_j = r (cos theta_j, sin theta_j). The
mirror is rigid (mass M, inertia J about x and y); its motion is q = (tip, tilt, piston) =
(theta_x, theta_y, z) in (rad, rad, m), and the point p_j moves by

    z_j = z + theta_x y_j - theta_y x_j,      i.e. z_mirror = P q,  P_j = (y_j, -x_j, 1).

Mechanics per leg (all assumed, in the plant file ``plants/fsm_*.toml``): the stack (k_p, its
own plant file) in series with the lever's compliance k_s, so the stack's top end is massless
and its elongation is x = (F + k_s u)/(k_p + k_s) for the lever input motion u = z_j / a and the
stack force F (T_em V_p + F_e); a guide flexure k_g holds the mirror at the leg. The mirror's
three rigid-body modes follow from

    M_u u'' + K_u u = beta F,   M_u = H^T diag(J, J, M) H,  H = a P^{-1},
    K_u = diag(k_s k_p/(k_s + k_p) + a^2 k_g),  beta = k_s / (k_p + k_s),

and the stack sees x = F/(k_p + k_s) + beta u: residual compliance 1/(k_p + k_s) (diagonal, as
:class:`~workbench.plant.structure.Structure` asks) and mode participation beta phi. The housing
rocks on its bracket (inertia I_h about x and y, bracket stiffness k_b = (2 pi f_h)^2 (I_h + J)
from the rocking frequency f_h with the mirror locked) and carries the stacks' bases, so the
coordinates are (u, phi_x, phi_y), the mirror's angles are H u + phi, and

    M = [[H^T Mq H, H^T Mq E], [E^T Mq H, E^T Mq E + I_h]],   K = blockdiag(K_u, k_b),

(Mq = diag(J, J, M), E picks tip and tilt): five modes, each damped by its share of strain
energy in the flexures and in the bracket (modal strain energy). The stack forces act on u only
(they push mirror and housing apart), so at DC the housing does not move.

Outputs of the structure after the stack elongations and rates: tip_rad, tilt_rad, piston_m.
External inputs after the stack forces: torques about x and y (N m) and a force along the
mirror axis (N), collocated with those outputs (input participation = output participation).

Kinematics: quasi-statically each lever input is u_j = g_j x_j with the static transmission
g_j = beta K_u^-1 / (1/(k_p + k_s) + beta^2 K_u^-1) (load sharing between stack and lever), so
q = K x with K = a P^{-1} diag(g) and x = K^{-1} q. For stacks at 90/210/330 deg this is
tip = a g (x_1 - (x_2 + x_3)/2) / (1.5 r), tilt = a g (x_2 - x_3) / (sqrt(3) r),
piston = a g (x_1 + x_2 + x_3)/3. At DC this is exactly the structure's static map
(:attr:`FastSteeringMirror.kinematic_error`).
"""

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.linalg

from ..errors import PlantDefinitionError
from ..fields import Field, check_table, check_value, read_toml
from .coupled import CoupledSimulator
from .files import load_plant
from .hysteresis import PrandtlIshlinskii
from .structure import modal_structure

__all__ = ["FastSteeringMirror", "MirrorTrajectory", "load_mirror", "mirror_stack_files", "mirror_run", "FSM_SCHEMA_VERSION",
           "AXES"]

FSM_SCHEMA_VERSION = "workbench.fsm/1"
AXES = ("tip_rad", "tilt_rad", "piston_m")

_SCHEMA = {
    "": {"schema": Field("str", expect=f'the string "{FSM_SCHEMA_VERSION}"'),
         "name": Field("str", expect="a descriptive name")},
    "stacks": {"files": Field("strs", expect="three plant files relative to this file, e.g. \"p888_51_sn637.toml\""),
               "angles_deg": Field("floats", -360.0, 360.0, expect="one angle in deg per stack, e.g. [90, 210, 330]")},
    "geometry": {"radius_m": Field("float", 0.0, 1.0, lo_open=True, expect="the stacks' radius in m, e.g. 0.020"),
                 "amplification": Field("float", 0.0, 100.0, lo_open=True,
                                        expect="the lever flexure's mirror-side / stack-side motion, e.g. 5.0")},
    "mirror": {"mass_kg": Field("float", 0.0, 100.0, lo_open=True, expect="the moving mass in kg, e.g. 0.2"),
               "inertia_kg_m2": Field("float", 0.0, 10.0, lo_open=True,
                                      expect="the inertia about the tip and tilt axes in kg m^2, e.g. 3e-5")},
    "flexures": {"series_stiffness_n_per_m": Field("float", 0.0, 1e12, lo_open=True,
                                                   expect="each lever's stiffness in series with its stack, N/m, e.g. 5e7"),
                 "guide_stiffness_n_per_m": Field("float", 0.0, 1e12,
                                                  expect="each guide flexure's stiffness at the mirror, N/m, >= 0"),
                 "damping_ratio": Field("float", 0.0, 1.0, lo_open=True, expect="a damping ratio in (0, 1]")},
    "housing": {"inertia_kg_m2": Field("float", 0.0, 100.0, lo_open=True,
                                       expect="the housing's rocking inertia about x and y in kg m^2, e.g. 3e-4"),
                "rocking_freq_x_hz": Field("float", 0.0, 1e6, lo_open=True,
                                           expect="the rocking frequency about x (mirror locked) in Hz"),
                "rocking_freq_y_hz": Field("float", 0.0, 1e6, lo_open=True,
                                           expect="the rocking frequency about y (mirror locked) in Hz"),
                "damping_ratio": Field("float", 0.0, 1.0, lo_open=True, expect="a damping ratio in (0, 1]")},
}


def _check(path, key, field, value):
    if field.kind == "strs":
        if not (isinstance(value, list) and value and all(isinstance(v, str) and v.strip() for v in value)):
            raise PlantDefinitionError(path, key, f"got {value!r}; expected a list of {field.expect}")
        return list(value)
    return check_value(path, key, field, value, PlantDefinitionError)


def _table(path, section, table):
    return check_table(path, section, table, _SCHEMA[section], PlantDefinitionError, sections=_SCHEMA,
                       check=_check)


@dataclass(frozen=True)
class FastSteeringMirror:
    """A three-stack tip/tilt/piston mirror: the stacks' plants, geometry, mirror and flexures (SI).

    Parameters
    ----------
    plants : tuple of Plant
        The stacks' plant files, in stack order.
    angles_deg : ndarray, shape (3,)
        Stack positions, deg from the x axis.
    radius_m, amplification : float
        Stack radius (m) and lever amplification (mirror-side / stack-side motion).
    mass_kg, inertia_kg_m2 : float
        Mirror (with its moving cell): mass, and inertia about the tip and tilt axes.
    series_stiffness_n_per_m, guide_stiffness_n_per_m : float
        Lever flexure in series with each stack; guide flexure at each leg on the mirror side.
    damping_ratio : float
        Damping ratio of motion that strains the flexures.
    housing_inertia_kg_m2, rocking_freq_x_hz, rocking_freq_y_hz, housing_damping_ratio : float
        The housing on its bracket: rocking inertia, rocking frequencies with the mirror locked,
        damping ratio of motion that strains the bracket.
    name, source : str
    """

    plants: tuple
    angles_deg: np.ndarray
    radius_m: float
    amplification: float
    mass_kg: float
    inertia_kg_m2: float
    series_stiffness_n_per_m: float
    guide_stiffness_n_per_m: float
    damping_ratio: float
    housing_inertia_kg_m2: float
    rocking_freq_x_hz: float
    rocking_freq_y_hz: float
    housing_damping_ratio: float
    name: str = ""
    source: str = ""

    def __post_init__(self):
        if len(self.plants) != 3 or np.asarray(self.angles_deg).shape != (3,):
            raise ValueError("a tip/tilt/piston mirror needs exactly three stacks and three angles")
        if abs(np.linalg.det(self.point_matrix)) < 1e-6 * self.radius_m ** 2:
            raise ValueError(f"stacks at {list(self.angles_deg)} deg cannot set tip, tilt and piston "
                             f"independently (two at the same angle or all on a line)")

    # -- geometry ------------------------------------------------------------------------
    @property
    def stacks(self):
        """The stacks' PZTParams, in order."""
        return [p.pzt for p in self.plants]

    @property
    def positions_m(self):
        """Stack positions (x_j, y_j), m, shape (3, 2)."""
        th = np.radians(np.asarray(self.angles_deg, float))
        return self.radius_m * np.column_stack([np.cos(th), np.sin(th)])

    @property
    def point_matrix(self):
        """P: mirror displacement at each stack (m) per (tip rad, tilt rad, piston m); rows (y_j, -x_j, 1)."""
        p = self.positions_m
        return np.column_stack([p[:, 1], -p[:, 0], np.ones(3)])

    @property
    def _k(self):
        kp = np.array([pz.stiffness_n_per_m for pz in self.stacks])
        ks, kg, a = self.series_stiffness_n_per_m, self.guide_stiffness_n_per_m, self.amplification
        k_u = ks * kp / (ks + kp) + a * a * kg
        beta = ks / (kp + ks)
        resid = 1.0 / (kp + ks)
        return kp, k_u, beta, resid

    @property
    def transmission(self):
        """g_j: static lever input per stack elongation (load sharing), dimensionless."""
        _, k_u, beta, resid = self._k
        return beta / k_u / (resid + beta * beta / k_u)

    @property
    def kinematics(self):
        """K: (tip rad, tilt rad, piston m) per stack elongation (m), static, from the geometry."""
        return self.amplification * np.linalg.solve(self.point_matrix, np.diag(self.transmission))

    @property
    def inverse_kinematics(self):
        """K^-1: stack elongations (m) per (tip rad, tilt rad, piston m)."""
        return np.diag(1.0 / self.transmission) @ self.point_matrix / self.amplification

    # -- mechanics -----------------------------------------------------------------------
    def modes(self):
        """The five modes: frequencies (Hz), damping ratios, shapes (columns over u, phi_x, phi_y, max |u or r phi| = 1), H, M, K."""
        _, k_u, _, _ = self._k
        h = self.amplification * np.linalg.inv(self.point_matrix)   # mirror q per lever input u
        mq = np.diag([self.inertia_kg_m2, self.inertia_kg_m2, self.mass_kg])
        e = np.eye(3)[:, :2]
        i_h, j = self.housing_inertia_kg_m2, self.inertia_kg_m2
        k_b = (2 * np.pi * np.array([self.rocking_freq_x_hz, self.rocking_freq_y_hz])) ** 2 * (i_h + j)
        m = np.block([[h.T @ mq @ h, h.T @ mq @ e], [e.T @ mq @ h, e.T @ mq @ e + i_h * np.eye(2)]])
        k = np.diag(np.concatenate([k_u, k_b]))
        w2, phi = scipy.linalg.eigh(k, m)
        scale = np.concatenate([np.ones(3), np.full(2, self.radius_m)])
        phi = phi / np.abs(phi * scale[:, None]).max(axis=0)
        strain = phi * (k @ phi)                     # strain energy per coordinate and mode
        share_b = strain[3:].sum(axis=0) / strain.sum(axis=0)
        zeta = (1 - share_b) * self.damping_ratio + share_b * self.housing_damping_ratio
        return np.sqrt(w2) / (2 * np.pi), zeta, phi, h, m, k

    def structure(self):
        """M(.) of the three stacks as a modal :class:`~workbench.plant.structure.Structure`.

        Modes: the five of :meth:`modes`. Outputs after the elongations and rates: ``tip_rad``,
        ``tilt_rad``, ``piston_m`` (the mirror's, inertial); external inputs after the stack
        forces: torques about x and y (N m) and the piston force (N) on the mirror (collocated).
        """
        _, _, beta, resid = self._k
        freqs, zeta, phi, h, m, _ = self.modes()
        masses = np.einsum("ji,jk,ki->i", phi, m, phi)
        psi = (beta[:, None] * phi[:3]).T            # modes x stacks
        outp = (np.hstack([h, np.eye(3)[:, :2]]) @ phi).T   # modes x (tip, tilt, piston)
        k_static = 1.0 / (resid + (psi ** 2 / (masses * (2 * np.pi * freqs) ** 2)[:, None]).sum(axis=0))
        return modal_structure(freqs, zeta, masses, np.zeros_like(psi), psi, k_static,
                               input_participation=outp, output_participation=outp, output_names=AXES)

    @property
    def kinematic_error(self):
        """Largest relative difference between the structure's static map x -> q and :attr:`kinematics`."""
        st = self.structure()
        dc = st.d - st.c @ np.linalg.solve(st.a, st.b)
        k_dc = dc[6:9, :3] @ np.linalg.inv(dc[:3, :3])
        return float(np.abs(k_dc - self.kinematics).max() / np.abs(self.kinematics).max())

    def with_capacitance_scales(self, c_h_scales):
        """The same mirror with each stack's C_h (every play weight) scaled by ``c_h_scales[j]``.

        The three serial files share one assumed C_h shape (seed 000 tabulates none); this is
        how a study makes the stacks' hysteresis unequal (PI's capacitance tolerance is +/-20 %).
        """
        sc = np.asarray(c_h_scales, float)
        if sc.shape != (3,) or np.any(sc <= 0):
            raise ValueError(f"need three positive scale factors; got {c_h_scales}")
        plants = []
        for pl, k in zip(self.plants, sc):
            h = pl.pzt.hysteresis
            ch = PrandtlIshlinskii(h.thresholds, h.weights * k, h.initial_states)
            plants.append(dataclasses.replace(pl, pzt=dataclasses.replace(pl.pzt, hysteresis=ch)))
        return dataclasses.replace(self, plants=tuple(plants))

    def simulator(self, dt_s, n_sub=1, terminations=None):
        """A :class:`~workbench.plant.coupled.CoupledSimulator` of the three stacks on :meth:`structure`."""
        return CoupledSimulator(self.stacks, self.structure(), dt_s, n_sub, terminations)


@dataclass(frozen=True)
class MirrorTrajectory:
    """Mirror and per-stack outputs of a run (SI). Stack arrays have shape (samples, 3).

    Attributes
    ----------
    t_s : ndarray
    tip_rad, tilt_rad, piston_m : ndarray
        Mirror rotation about x, about y, and its axial motion.
    x_m, q_c, i_a, v_t_v : ndarray
        Per stack: elongation (the gauge's measurand), charge, mean current, terminal voltage.
    coupled : CoupledTrajectory
        Everything the coupled kernel records.
    """

    t_s: np.ndarray
    tip_rad: np.ndarray
    tilt_rad: np.ndarray
    piston_m: np.ndarray
    x_m: np.ndarray
    q_c: np.ndarray
    i_a: np.ndarray
    v_t_v: np.ndarray
    coupled: object


def mirror_run(sim, v_pea_v, external=None, decimate=1):
    """Drive the three stacks of a mirror simulator (from :meth:`FastSteeringMirror.simulator`).

    Parameters
    ----------
    sim : CoupledSimulator
    v_pea_v : array_like, shape (samples, 3)
        Amplifier command per stack, V.
    external : array_like, shape (samples, 3), optional
        Torque about x (N m), torque about y (N m), piston force (N) on the mirror.
    decimate : int
    """
    v = np.asarray(v_pea_v, float)
    if v.ndim != 2 or v.shape[1] != 3:
        raise ValueError(f"v_pea_v needs shape (samples, 3), one column per stack; got {v.shape}")
    tr = sim.run(v, external_n=external, decimate=decimate)
    ns = 3
    return MirrorTrajectory(t_s=tr.t_s, tip_rad=tr.y[:, 2 * ns], tilt_rad=tr.y[:, 2 * ns + 1],
                            piston_m=tr.y[:, 2 * ns + 2], x_m=tr.x_m, q_c=tr.q_c, i_a=tr.i_a,
                            v_t_v=tr.v_t_v, coupled=tr)


def mirror_stack_files(path):
    """The stack plant files a mirror file names (``[stacks] files``, resolved against its folder): (key, Path)
    pairs; [] when ``path`` is not a readable mirror file (its loader reports what is wrong)."""
    import tomllib
    path = Path(path)
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        return []
    stacks = doc.get("stacks") if doc.get("schema") == FSM_SCHEMA_VERSION else None
    files = stacks.get("files") if isinstance(stacks, dict) else None
    if not isinstance(files, list):
        return []
    return [(f"{path}: stacks.files[{j}]", path.parent / f) for j, f in enumerate(files) if isinstance(f, str)]


def load_mirror(path):
    """Load and validate a mirror file (``plants/fsm_*.toml``).

    Raises
    ------
    PlantDefinitionError
        Naming the file and key on a syntax error, an unknown or missing key or section, a
        wrong type, sign or range, a stack file that does not load, or a degenerate geometry.
    """
    path = Path(path)
    doc = read_toml(path, PlantDefinitionError)
    known = ("stacks", "geometry", "mirror", "flexures", "housing")
    if doc.get("schema") != FSM_SCHEMA_VERSION and isinstance(doc.get("electrical"), dict):
        # a single-stack plant file where a mirror is wanted: say so, not "unknown section [electrical]"
        raise PlantDefinitionError(path, "schema", f"is a single-stack plant file (it has [electrical]), not a "
                                                   f"three-stack mirror ({FSM_SCHEMA_VERSION!r}); give a mirror "
                                                   f"file such as plants/fsm_p888_51.toml, which names its stacks")
    for key, value in doc.items():
        if isinstance(value, (dict, list)) and key not in _SCHEMA:
            raise PlantDefinitionError(path, key, f"unknown section; known sections: {', '.join(known)}")
    top = _table(path, "", doc)
    if top["schema"] != FSM_SCHEMA_VERSION:
        raise PlantDefinitionError(path, "schema", f"got {top['schema']!r}; expected {FSM_SCHEMA_VERSION!r}")
    sec = {}
    for name in known:
        if not isinstance(doc.get(name), dict):
            raise PlantDefinitionError(path, name, "section missing or not a table; see plants/fsm_p888_51.toml")
        sec[name] = _table(path, name, doc[name])
    files, angles = sec["stacks"]["files"], sec["stacks"]["angles_deg"]
    if len(files) != 3:
        raise PlantDefinitionError(path, "stacks.files", f"got {len(files)} files; a tip/tilt/piston mirror "
                                   f"needs exactly three")
    if angles.size != 3:
        raise PlantDefinitionError(path, "stacks.angles_deg", f"got {angles.size} angles; expected three, "
                                   f"one per file")
    plants = []
    for j, f in enumerate(files):
        try:
            pl = load_plant(path.parent / f)
        except PlantDefinitionError as err:
            raise PlantDefinitionError(path, f"stacks.files[{j}]", f"{f!r} does not load: {err}") from err
        if pl.structure is not None:
            raise PlantDefinitionError(path, f"stacks.files[{j}]", f"{f!r} has its own [structure]; the mirror "
                                       f"is the structure, give the bare stack's file")
        if pl.pzt.series_resistance_ohm <= 0:
            raise PlantDefinitionError(path, f"stacks.files[{j}]", f"{f!r} has R = 0 (series_resistor_in = "
                                       f"false); the mirror's coupled model needs the series resistor in")
        plants.append(pl)
    try:
        return FastSteeringMirror(plants=tuple(plants), angles_deg=angles, name=top["name"], source=str(path),
                                  housing_inertia_kg_m2=sec["housing"]["inertia_kg_m2"],
                                  rocking_freq_x_hz=sec["housing"]["rocking_freq_x_hz"],
                                  rocking_freq_y_hz=sec["housing"]["rocking_freq_y_hz"],
                                  housing_damping_ratio=sec["housing"]["damping_ratio"], **sec["geometry"], **sec["mirror"], **sec["flexures"])
    except ValueError as err:
        raise PlantDefinitionError(path, "stacks.angles_deg", str(err)) from err
