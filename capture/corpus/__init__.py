"""Jobs over many recordings: choosing one file per trial (capture.corpus.selection),
synthesizing sessions (synth, dataset), replaying a model over recordings (replay),
tables for analysis (export), and running the work locally or on a Ray cluster (cluster).
"""
