"""The benchmark figures (PNG): work-precision per scene and RK4's stability limit."""
import math
from pathlib import Path

import numpy as np

from .work_precision import METHOD_BY_KEY


def plot_all(results, limits, default, outdir, cfg):
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    paths = {}
    colors = plt.get_cmap('tab10').colors
    for res in results:
        fig, axes = plt.subplots(1, 2, figsize=(13.5, 6.4))
        for i, (key, points) in enumerate(res.curves.items()):
            m = METHOD_BY_KEY[key]
            pts = [p for p in points if p.ok]
            ls, marker = m.style
            lw = 2.2 if m.project else 1.3
            w = np.array([p.wall for p in pts])
            for ax, attr in zip(axes, ('phi4_err', 'switch_err'), strict=True):
                e = np.array([getattr(p, attr) for p in pts])
                keep = np.isfinite(e) & (e > 0)
                if keep.any():
                    ax.plot(np.log10(w[keep]), np.log10(e[keep]), ls, marker=marker,
                            color=colors[i % 10], lw=lw, ms=6, label=m.label)
        for ax, what in zip(axes, ('relative error of φ4 at the end',
                                   'switch-time error max |Δt| [s]'), strict=True):
            for t, txt in ((res.duration, 'real time'), (res.duration / 1000, '1000× real time')):
                ax.axvline(math.log10(t), color='0.5', lw=0.8, ls='-.')
                ax.text(math.log10(t), 0.02, ' ' + txt, rotation=90, color='0.35', fontsize=8,
                        transform=ax.get_xaxis_transform(), va='bottom', ha='right')
            ax.set_xlabel('log10 wall time [s]  (minimum of several runs)')
            ax.set_ylabel(f'log10 {what}')
            ax.grid(True, alpha=0.3)
            span = math.log10(res.duration)
            top = ax.secondary_xaxis('top', functions=(lambda x, s=span: s - x,
                                                       lambda r, s=span: s - r))
            top.set_xlabel('log10 real-time factor', fontsize=8, labelpad=2)
            top.tick_params(labelsize=8)
        if default and res.name == 'paper':
            p = default['point']
            axes[0].plot(math.log10(p.wall), math.log10(p.phi4_err), '*', color='k', ms=16,
                         zorder=5, label='defaults (dopri5, rtol 2e-6)')
            if math.isfinite(p.switch_err) and p.switch_err > 0:
                axes[1].plot(math.log10(p.wall), math.log10(p.switch_err), '*', color='k',
                             ms=16, zorder=5)
        axes[0].set_title('φ4 error (switch counts may differ)', fontsize=10, pad=10)
        axes[1].set_title('switch-time error (runs with the reference\'s switch count)',
                          fontsize=10, pad=10)
        handles, labels = axes[0].get_legend_handles_labels()
        fig.legend(handles, labels, loc='lower center', ncol=5, fontsize=9, frameon=False)
        fig.suptitle(f'Work-precision: scene "{res.name}", {res.duration:g} s simulated '
                     f'(reference: {res.reference.label.split(", atol")[0]}'
                     f'{", output integrated" if "integrated" in res.reference.label else ""})',
                     fontsize=12)
        fig.tight_layout(rect=(0.0, 0.09, 1.0, 1.0))
        path = outdir / f'work_precision_{res.name}.png'
        fig.savefig(path, dpi=110)
        plt.close(fig)
        paths[res.name] = path
    if limits:
        fig, ax = plt.subplots(figsize=(7.5, 5.2))
        for j, formulation in enumerate(cfg.stability_formulations):
            rows = [r for r in limits if r['formulation'] == formulation]
            c = np.array([r['c'] for r in rows])
            ax.loglog(c, [r['limit'] for r in rows], 'o-' if j == 0 else 's--',
                      ms=11 if j == 0 else 6, color=colors[j], zorder=3 + j,
                      label=f'limit (energy criterion), {formulation} formulation')
            ax.loglog(c, [r['limit_growth'] for r in rows], 'o:' if j == 0 else 's:',
                      ms=9 if j == 0 else 5, color=colors[j], mfc='none', zorder=3 + j,
                      label=f'limit (growth criterion), {formulation} formulation')
        rows = [r for r in limits if r['formulation'] == cfg.stability_formulations[0]]
        c = np.array([r['c'] for r in rows])
        ax.loglog(c, [r['theory'] for r in rows], 'k:', lw=1.5,
                  label='theory 2√2 / λ (the bound on the engaged twist mode)')
        ax.loglog(c, [r['h_auto'] for r in rows], '^-', color=colors[2],
                  label='real-time mode sub-step (refine_step auto)')
        ax.set_xlabel('shaft stiffness c [N·m/rad]  (J3 = 1e-3, J4 = 0.5 kg·m²)')
        ax.set_ylabel('fixed step h [s]')
        ax.set_title('Stability limit of fixed-step RK4 (refine_step off), paper scene')
        ax.grid(True, which='both', alpha=0.3)
        ax.legend(fontsize=8)
        fig.tight_layout()
        path = outdir / 'stability_limit.png'
        fig.savefig(path, dpi=110)
        plt.close(fig)
        paths['stability'] = path
    return paths
