"""Jobs over many recordings: choosing one file per trial (capture.corpus.selection),
synthesizing sessions (synth, dataset), replaying a model over recordings (replay),
tables for analysis (export), and running the work here, in processes or on a Ray cluster
(jobs, with the cluster's connection and DDP training in cluster).
"""
