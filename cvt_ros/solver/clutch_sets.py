"""The engaged set of an N-path machine as the layers above the core see it: one change per
switching instant.

The N-path core reports one ClutchSwitch per clutch that switched (a handoff — one path engaging
as another releases — is two switches at the same time, in path order). A device, a recording or
a scenario wants the set after each instant: :func:`set_changes` groups the switches by time and
gives each group's set before and after, so "any clutch engaged" (``clutch_engaged``) changes
only where it really does (not off and on again inside a handoff).
"""
from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class SetChange:
    """The engaged set at one switching instant: time [s], the set before and after it
    (bitmasks, bit k − 1 = path k), and the switches (ClutchSwitch) that made it."""
    t: float
    before: int
    after: int
    switches: tuple = ()

    @property
    def engaged(self):
        """Is any clutch engaged after it?"""
        return self.after != 0

    @property
    def any_changed(self):
        """Did "any clutch engaged" change here (not a handoff between paths)?"""
        return (self.before != 0) != (self.after != 0)

    @property
    def kind(self):
        """'set' (never 'graze': grazing contacts are left out)."""
        return 'set'


def switch_tuples(switches):
    """(t, engaged, path) of each switch: ClutchSwitch objects (grazes left out) or tuples
    (t, engaged[, path]) as plants report them (path 1 when there is none)."""
    out = []
    for s in switches:
        if isinstance(s, tuple):
            out.append((s[0], bool(s[1]), s[2] if len(s) > 2 else 1))
        elif s.kind != 'graze':
            out.append((s.t, s.engaged, s.path))
    return out


def set_changes(switches, mask):
    """``switches`` (ClutchSwitch with ``path`` or (t, engaged, path) tuples, in time order;
    grazes are skipped) from the engaged set ``mask`` → (list of SetChange, the set after the
    last); each SetChange keeps its switches as they were given."""
    changes = []
    group = []
    before = after = mask
    t_group = None
    for s, (t, engaged, path) in zip(_kept(switches), switch_tuples(switches), strict=True):
        if group and t != t_group:
            changes.append(SetChange(t_group, before, after, tuple(group)))
            group, before = [], after
        bit = 1 << (path - 1)
        after = after | bit if engaged else after & ~bit
        group.append(s)
        t_group = t
    if group:
        changes.append(SetChange(t_group, before, after, tuple(group)))
    return changes, after


def _kept(switches):
    return [s for s in switches if isinstance(s, tuple) or s.kind != 'graze']


def any_switches(switches, mask):
    """(t, engaged) at each instant where "any clutch engaged" changes, from ``mask``."""
    changes, _ = set_changes(switches, mask)
    return [(c.t, c.engaged) for c in changes if c.any_changed]


def path_masks(row_engaged):
    """The engaged set of a sample's ``engaged_1 … engaged_N`` values."""
    return sum(1 << k for k, e in enumerate(row_engaged) if e > 0.5)


__all__ = ['SetChange', 'any_switches', 'path_masks', 'set_changes', 'switch_tuples']
