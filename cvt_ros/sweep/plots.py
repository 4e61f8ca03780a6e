"""The campaign's summary figure (``OUT/summary.png``, matplotlib Agg): what a controls engineer
looks at first.

* **Maps** (top row) when the cases form a grid over two parameters x × y (the campaign's
  ``summary: {x, y}``, else its first two numeric parameters): each summary metric as a colour
  map over the grid, its value written in each cell; failed cases crossed out in red, cases
  without a steady state hatched.
* **Metric vs parameter** (bottom row): each summary metric over x, one line per value of y (a
  grid) or points coloured by y (random / Latin hypercube / explicit cases); failed cases as red
  crosses on the axis.

The summary metrics are ``summary: {metrics: [...]}`` or the campaign's first two.
"""
import math

import numpy as np

from .metrics import SCENARIO_METRICS, SCENE_METRICS
from .table import is_number, unit_of

DPI = 110


def _plt():
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    return plt


def _label(name, kind):
    units = SCENE_METRICS if kind == 'scene' else SCENARIO_METRICS
    unit = units[name][0] if name in units else unit_of(name)
    return f"{name} [{unit}]" if unit and unit != '-' else name


def _axes(campaign, rows):
    numeric = [n for n in campaign.variable_names if all(is_number(r.get(n)) for r in rows)]
    x = campaign.summary.get('x') or (numeric[0] if numeric else campaign.variable_names[0])
    y = campaign.summary.get('y') or next((n for n in numeric if n != x), None)
    return x, y


def _grid(rows, x, y, names):
    """(xs, ys) if every (x, y) pair occurs once and the other parameters do not vary."""
    if y is None or len({tuple(r.get(n) for n in names if n not in (x, y)) for r in rows}) > 1:
        return None
    if not all(is_number(r.get(x)) and is_number(r.get(y)) for r in rows):
        return None
    pairs = {(r[x], r[y]) for r in rows}
    xs, ys = sorted({p[0] for p in pairs}), sorted({p[1] for p in pairs})
    if len(pairs) != len(rows) or len(pairs) != len(xs) * len(ys) or len(xs) < 2 or len(ys) < 2:
        return None
    return xs, ys


def _log_axes(campaign):
    return {v.name for v in campaign.variables if v.scale == 'log'}


def _value(row, metric):
    v = row.get(metric)
    return math.nan if v is None or row.get('status') != 'ok' else float(v)


def _short(value, digits=3):
    """A number in few characters: 1.6e3, not 1.59e+03 (tick and cell labels side by side)."""
    if not isinstance(value, (int, float, np.floating, np.integer)):
        return str(value)
    if 100.0 <= abs(value) < 1e4:
        return f"{value:.0f}"   # 116 rather than 1.2e2
    text = f"{value:.{digits}g}"
    mantissa, e, exponent = text.partition('e')
    return mantissa + e + str(int(exponent)) if e else text


def _map(ax, fig, rows, x, y, xs, ys, metric, kind):
    """A colour map on the grid's cells, one cell per case (axes by index: uneven lists and log
    ranges get equal cells), the value written in each."""
    z = np.full((len(ys), len(xs)), np.nan)
    at = {(r[x], r[y]): r for r in rows}
    for i, yv in enumerate(ys):
        for j, xv in enumerate(xs):
            z[i, j] = _value(at[(xv, yv)], metric)
    mesh = ax.pcolormesh(np.arange(len(xs) + 1) - 0.5, np.arange(len(ys) + 1) - 0.5,
                         np.ma.masked_invalid(z), cmap='viridis', shading='flat')
    fig.colorbar(mesh, ax=ax, label=_label(metric, kind))
    finite = z[np.isfinite(z)]
    mid = 0.5 * (finite.min() + finite.max()) if len(finite) else 0.0
    digits = 3 if len(xs) <= 6 else 2   # what fits a cell at 6 pt
    for i, yv in enumerate(ys):
        for j, xv in enumerate(xs):
            row = at[(xv, yv)]
            if row.get('status') != 'ok':
                ax.plot(j, i, 'x', color='red', ms=10, mew=2)
            elif math.isfinite(z[i, j]):
                ax.text(j, i, _short(z[i, j], digits), ha='center', va='center', fontsize=6,
                        color='white' if z[i, j] < mid else 'black')
            if row.get('steady') is False:
                ax.add_patch(_hatch(j, i))
    step_x = max(1, len(xs) // 8)
    ax.set_xticks(range(0, len(xs), step_x), [_short(v) for v in xs[::step_x]],
                  rotation=45 if len(xs[::step_x]) > 5 else 0)
    step_y = max(1, len(ys) // 10)
    ax.set_yticks(range(0, len(ys), step_y), [_short(v) for v in ys[::step_y]])
    ax.set_xlabel(_label(x, kind))
    ax.set_ylabel(_label(y, kind))
    ax.set_title(metric)


def _hatch(j, i):
    from matplotlib.patches import Rectangle
    return Rectangle((j - 0.5, i - 0.5), 1.0, 1.0, fill=False, hatch='///', edgecolor='0.5',
                     lw=0)


def _lines(ax, fig, rows, x, y, grid, metric, kind, logs):
    failed = [r for r in rows if r.get('status') != 'ok' and is_number(r.get(x))]
    ok = [r for r in rows if r.get('status') == 'ok']
    if grid is not None:
        cmap = _plt().get_cmap('plasma')
        for k, yv in enumerate(grid[1]):
            pts = sorted((r[x], _value(r, metric)) for r in ok if r[y] == yv)
            if pts:
                px, py = zip(*pts, strict=True)
                ax.plot(px, py, 'o-', ms=3, color=cmap(k / max(len(grid[1]) - 1, 1)),
                        label=f"{y} = {yv:.4g}")
        ax.legend(fontsize=6)
    elif y is not None and all(is_number(r.get(y)) for r in ok) and ok:
        sc = ax.scatter([r[x] for r in ok], [_value(r, metric) for r in ok],
                        c=[r[y] for r in ok], s=12, cmap='plasma')
        fig.colorbar(sc, ax=ax, label=_label(y, kind))
    else:
        pts = sorted((r[x], _value(r, metric)) for r in ok if is_number(r.get(x)))
        if pts:
            ax.plot(*zip(*pts, strict=True), 'o-', ms=3)
    if failed:
        ax.plot([r[x] for r in failed], [0.0] * len(failed), 'x', color='red', ms=8, mew=2,
                transform=ax.get_xaxis_transform(), clip_on=False, label='failed')
    if x in logs:
        ax.set_xscale('log')
    else:
        ax.ticklabel_format(axis='x', style='sci', scilimits=(-2, 4))
    ax.set_xlabel(_label(x, kind))
    ax.set_ylabel(_label(metric, kind))
    ax.grid(alpha=0.3)


def title_notes(campaign, rows, x, y):
    """What the summary's title says of its cases: counts, failures, unsteady ones, and the
    varied parameters the axes x, y do not tell apart."""
    failed = sum(r.get('status') != 'ok' for r in rows)
    unsteady = sum(r.get('steady') is False for r in rows)
    notes = [f"{len(rows)} cases", f"{failed} failed (red ×)"]
    if unsteady:
        notes.append(f"{unsteady} without a steady state (hatched)")
    others = [n for n in campaign.variable_names if n not in (x, y)
              and len({repr(r.get(n)) for r in rows}) > 1]
    if others:   # a third varied parameter: its cases lie on top of each other here
        notes.append(f"{', '.join(others)} also varied, not told apart here (the table has "
                     f"them; summary: x, y picks the axes)")
    return notes


def plot_summary(campaign, rows, path):
    """Draw the summary figure of ``rows`` (the table's rows) to ``path``; returns ``path``, or
    None when there is nothing to draw (no case, or no numeric parameter)."""
    x, y = _axes(campaign, rows)
    if not rows or not all(is_number(r.get(x)) for r in rows):
        return None
    metrics = list(campaign.summary.get('metrics') or campaign.metrics[:2])
    grid = _grid(rows, x, y, campaign.variable_names)
    plt = _plt()
    n_rows = 2 if grid is not None else 1
    fig, axes = plt.subplots(n_rows, len(metrics), figsize=(5.2 * len(metrics), 4.2 * n_rows),
                             squeeze=False, constrained_layout=True)
    logs = _log_axes(campaign)
    for k, metric in enumerate(metrics):
        if grid is not None:
            _map(axes[0, k], fig, rows, x, y, *grid, metric, campaign.kind)
        _lines(axes[-1, k], fig, rows, x, y, grid, metric, campaign.kind, logs)
    notes = title_notes(campaign, rows, x, y)
    name = campaign.name if len(campaign.name) <= 80 else f"{campaign.name[:80]}…"
    fig.suptitle(f"{name}: " + ', '.join(notes), fontsize=10 if len(notes) > 3 else None)
    fig.savefig(path, dpi=DPI)
    plt.close(fig)
    return path


__all__ = ['plot_summary', 'title_notes']
