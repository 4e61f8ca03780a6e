"""Test campaigns at scale: scene, scenario and controller-gain sweeps on Dask (issue 15).

    from cvt_ros.sweep import load_campaign, open_cluster, run_campaign
    campaign = load_campaign('config/campaigns/conveyor_ratio_map.yaml')
    with open_cluster(workers=2) as cluster:                 # or scheduler='tcp://host:8786'
        run = run_campaign(campaign, 'out/', cluster)       # → out/results.parquet
    run.rows[0]['mean_ratio'], run.failed

Rooms inside: campaign.py (the file, checked) → cases.py (expansion, per-case check, case ids)
→ runner.py (one case → one row, never raises) with metrics.py (the analysis room's figures) →
cluster.py (Dask: LocalCluster or an address, the submission window, faults) → table.py (Parquet
parts, resume, merge) and plots.py (summary PNG). Dask is imported only by cluster.py.
"""
from .campaign import Campaign, CampaignError, load_campaign
from .cases import CaseTask, build_tasks, expand
from .runner import run_case

__all__ = ['Campaign', 'CampaignError', 'CaseTask', 'build_tasks', 'expand', 'load_campaign',
           'open_cluster', 'run_campaign', 'run_case']


def __getattr__(name):   # Dask and the cluster code load only when a campaign runs
    if name in ('open_cluster', 'run_campaign', 'SweepError'):
        from . import cluster
        return getattr(cluster, name)
    raise AttributeError(name)
