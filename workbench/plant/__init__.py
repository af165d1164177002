"""Plant models: hysteresis operators, the Fig. 3 PZT, creep, the gauge chain, plant files."""

from .coupled import CoupledSimulator, CoupledTrajectory, structure_of
from .creep import CreepParams, LogCreepFit, log_creep, log_creep_fit
from .files import Plant, load_plant
from .gauge import (GaugeParams, GaugeReading, bridge_gain, bridge_output, chain_gain, design_trim,
                    four_probe_measure, four_probe_solve, gauge_run, gauge_run_equivalent)
from .hysteresis import PrandtlIshlinskii, play
from .pzt import Mode, PZTParams
from .simulator import PZTSimulator, Trajectory
from .structure import Structure, load_state_space, modal_structure, mode_filter, spring

__all__ = ["CreepParams", "LogCreepFit", "log_creep", "log_creep_fit", "Plant", "load_plant",
           "GaugeParams", "GaugeReading", "bridge_gain", "bridge_output", "chain_gain", "design_trim",
           "four_probe_measure", "four_probe_solve", "gauge_run", "gauge_run_equivalent",
           "PrandtlIshlinskii", "play", "Mode", "PZTParams", "PZTSimulator", "Trajectory",
           "Structure", "spring", "mode_filter", "modal_structure", "load_state_space",
           "CoupledSimulator", "CoupledTrajectory", "structure_of"]
