"""The N-path machine behind the Simulator's interface (issue 33): a scene with ``paths.count``
≥ 2 runs on a PathsSimulator (``fidelity.make_simulator`` makes it), the same methods (run,
advance, sample, commands, update_parameters, energy_balance) over the N-path core
(paths_hybrid.py).

What it adds: the sample rows carry per-path columns (output.path_columns: phi2_k, omega2_k,
engaged_k, clutch_torque_k), each ClutchSwitch names its path, ``path_switch_counts`` counts
each path's switches, ``engaged_set`` is the set of engaged clutches (bit k−1 = path k). Its
arrays live in one float and one int block as the Simulator's do (paths_layout.PF_*), so the
device's one-call period (period.paths_period) runs it too.

``PathsSimulator(values)`` at N = 1 runs the N-path core on the one-path machine: a private
switch for the tests, which hold it to the one-path core (test_paths.py).
"""
import numpy as np

from .. import parameters as params_mod
from ..physics import layout as L
from ..physics.clutch import KIND_GRAZE
from ..physics.linkage import rocker_angle
from ..physics.path_contacts import settle_contacts
from ..physics.paths import (
    N_PATH_AUX,
    N_PATH_PARAMS,
    P_OFFSET,
    path_parameters,
    paths_project,
    paths_rhs,
)
from . import advance_layout as AL
from . import paths_layout as PL
from .output import COL, path_columns
from .paths_hybrid import advance_paths
from .paths_steps import write_paths_sample
from .simulator import _KIND_NAMES, I_COUNTERS, I_MS, I_SIZE, ClutchSwitch, Simulator


class PathsSimulator(Simulator):
    """N identical crank-rocker paths on one crank, each with its own one-way clutch on J3
    (docs/physics.md §9). ``values`` as the Simulator's; ``paths.count`` sets N."""

    @property
    def steps_open_output(self):
        """Does the N-path loop integrate the open output with the input? Not where it is
        linear (P_LINEAR_OUTPUT): with every clutch open it runs apart, exactly
        (paths_open.py); with a clutch engaged it is the engaged shaft's mode, which the fixed
        step resolves anyway (simulator.stepped_rates)."""
        return not self.P[L.P_LINEAR_OUTPUT] > 0.0

    def __init__(self, values=None, events_capacity=4096):
        self.values = params_mod.validate(values or {})
        self.n_paths = self.values['paths.count']
        self.columns = path_columns(self.n_paths, per_path=True)
        self._events_buf = np.zeros((events_capacity, PL.N_PATH_EVENT_COLUMNS))
        self._floats = np.zeros(PL.PF_SIZE)
        self._ints = np.zeros(I_SIZE, dtype=np.int64)
        self._make_views()
        self._empty_grid = np.zeros(0)
        self._empty_out = np.zeros((0, len(self.columns)))
        self.reset()

    _VIEWS = Simulator._VIEWS + ('_row', '_dy', '_aux_block')

    def _make_views(self):
        f = self._floats
        n = L.N_STATE + self.n_paths
        self.y = f[PL.PF_Y:PL.PF_Y + n]
        self.P = f[PL.PF_P:PL.PF_ACT]
        self.ACT = f[PL.PF_ACT:PL.PF_S].reshape(L.N_ACT_SEGMENTS, 4)
        self.S = f[PL.PF_S:PL.PF_H]
        self.h_io = f[PL.PF_H:PL.PF_LEDGER]
        self.ledger = f[PL.PF_LEDGER:PL.PF_DY]
        self._dy = f[PL.PF_DY:PL.PF_DY + n]
        self._aux_block = f[PL.PF_AUX:PL.PF_ROW]
        self._row = f[PL.PF_ROW:PL.PF_ROW + len(self.columns)]   # the period's sample (period.py)
        self._scratch = f[PL.PF_SCRATCH:PL.PF_SIZE]
        self.ms = self._ints[I_MS:I_COUNTERS]
        self.counters = self._ints[I_COUNTERS:]

    @staticmethod
    def _parameter_vector(values):
        P = np.zeros(N_PATH_PARAMS)
        P[:L.N_PARAMS] = params_mod.parameter_vector(values)
        path_parameters(P, params_mod.phase_offsets(values))
        return P

    # ------------------------------------------------------------------ set-up
    def _set_rocker_from_linkage(self):
        P = self.P
        a = self.crank_length
        self.y[L.PHI2] = rocker_angle(self.y[L.PHI1] + P[P_OFFSET], a, P[L.P_B], P[L.P_D],
                                      P[L.P_H], P[L.P_SIGMA])
        paths_project(self.t, self.y, int(self.ms[0]), P, self.ACT, self._aux_block)

    def _settle_clutch(self):
        """The engaged set by complementarity, with one plastic impact shared by the rockers
        faster than the node (physics/path_contacts.py), decided afresh as for one path."""
        self.ms[0] = 0
        paths_project(self.t, self.y, 0, self.P, self.ACT, self._aux_block)
        mode, _, loss = settle_contacts(self.t, self.y, 0, 0, True, self.P, self.ACT, self._dy,
                                        self._aux_block, np.empty_like(self.y),
                                        np.empty_like(self.y))
        self.ledger[0] += loss
        self.ms[0] = mode
        self.ms[1] = 0   # the new guards start at zero: half-open rule

    # ------------------------------------------------------------------ state
    @property
    def engaged(self):
        """Is any clutch engaged?"""
        return self.ms[0] != 0

    @property
    def engaged_set(self):
        """The engaged clutches as a bitmask (bit k−1 = path k)."""
        return int(self.ms[0])

    # ------------------------------------------------------------------ integration
    def _call(self, t_end, grid, out, objects=True):
        self.t = advance_paths(self.t, t_end, self.y, self.ms, self.P, self.ACT, self.LIN,
                               self.S, self.h_io, grid, out, self._events_buf, self.counters,
                               self.ledger, self._scratch)
        return self._finish_call(objects)

    @staticmethod
    def _switches_of(rows):
        return [ClutchSwitch(row[AL.E_T], bool(int(row[AL.E_MODE]) >> int(row[PL.E_PATH]) & 1),
                             _KIND_NAMES[int(row[AL.E_KIND])], row[AL.E_VALUE],
                             int(row[PL.E_PATH]) + 1) for row in rows]

    def _count_path_switches(self, rows, switched):
        paths = rows[rows[:, AL.E_KIND] != KIND_GRAZE, PL.E_PATH].astype(np.int64)
        for k, count in enumerate(np.bincount(paths, minlength=self.n_paths)):
            self.path_switch_counts[k] += int(count)

    # ------------------------------------------------------------------ outputs
    def _aux(self):
        aux = np.empty(N_PATH_AUX)
        paths_rhs(self.t, self.y, int(self.ms[0]), self.P, self.ACT, np.empty_like(self.y), aux)
        return aux

    def sample(self):
        """The current state as one row of ``self.columns`` (angles with whole turns restored)."""
        row = np.empty(len(self.columns))
        write_paths_sample(row, self.t, self.y, int(self.ms[0]), self._aux(), self.P)
        row[COL['phi1']] += self.turns_phi1
        row[COL['phi3']] += self.turns_phi4
        row[COL['phi4']] += self.turns_phi4
        return row


__all__ = ['PathsSimulator']
