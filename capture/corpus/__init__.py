"""Jobs over many recordings: choosing one file per trial (selection), synthesizing
sessions (synth, dataset), replaying a model over recordings (replay), tables for analysis
(export), and running the work here, in processes or on a Ray cluster (jobs; the cluster's
connection and DDP training in cluster).

Public API: the modules `export` (`tables`, `corpus_tables`, `write`: recordings as
DataFrames, Parquet, CSV or MATLAB), `selection` (`select`: one file per trial) and `jobs`
(`run(tasks, where)` with `Task`, `LOCAL`, `Processes`, `Cluster`).
"""

from capture.corpus import export, jobs, selection

__all__ = ["export", "jobs", "selection"]
