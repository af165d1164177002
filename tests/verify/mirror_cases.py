"""A quick decoupled design for the mirror's export and verification tests (not design_mimo's search).

Per axis a PI + roll-off (:func:`workbench.design.loopshape.structured_controller`, integral
ratio 0.25, roll-off 8x, no lead, no notch) crossing at ``fc_hz`` on the nominal member's
decoupled diagonal (the gain k sets |C G_ii| = 1 there: derived from the plant), discretized as
design_mimo does. A crossover far below the flexure modes (~900 Hz) needs no notch.
"""

from types import SimpleNamespace

import control
import numpy as np

from workbench.design.antiwindup import discretize
from workbench.design.loopshape import structured_controller
from workbench.design.mimo import (AXIS_NAMES, G, decoupled, kinematic_decoupler, member_responses, nominal_name,
                                   tune_iff)
from workbench.linearize.mimo import mirror_family


def quick_design(fsm, fc_hz=60.0, dt_s=1e-4, iff=False):
    """``iff=True``: with the charge-bridge IFF tuned on the plant (:func:`workbench.design.mimo.tune_iff`)."""
    fam = mirror_family(fsm)
    nom = fam[nominal_name()]
    dec = kinematic_decoupler(fsm, nom)
    g = decoupled(dec, member_responses(nom, [fc_hz], G))[0]
    axes = {}
    for a, ax in enumerate(AXIS_NAMES):
        shape = structured_controller(1.0, fc_hz, 0.25, 1.0, 8.0)
        k = 1.0 / abs(complex(shape(2j * np.pi * fc_hz)) * g[a, a])
        c_d = control.ss(discretize(structured_controller(k, fc_hz, 0.25, 1.0, 8.0), dt_s, fc_hz))
        axes[ax] = SimpleNamespace(controller_d=c_d)
    damping = tune_iff(fsm, fam, source="bridge")[0] if iff else None
    return SimpleNamespace(iff=damping, decoupler=dec, axes=axes, notches={ax: None for ax in AXIS_NAMES}), fam
