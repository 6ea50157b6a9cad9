"""Recordings as tables: pandas DataFrames in Python, and files for other tools.

    python examples/export_tables.py recordings/ out/

`corpus_tables` reads every recording found (one file per trial: a replay or an older
copy of the same trial is left out) and concatenates their rows; each row names its
file, subject, condition and trial. docs/export.md describes every column.
"""

import sys

from capture.corpus import export

folder, out = sys.argv[1], sys.argv[2]

tables, corpus = export.corpus_tables([folder])
for name, df in tables.items():
    print(f"{name}: {len(df)} rows, {len(df.columns)} columns")

# One row per camera frame: the CNN's scores, the fused decision, the two references.
frames = tables["frames"]
print(frames[["file", "frame_index", "time_s", "cnn_decision", "decision", "label"]].head())

# Frames per trial and mode keyed live, the kind of summary a paper's table starts from.
print(frames.groupby(["file", "label"]).size().rename("frames").to_string())

# The same tables as files: "parquet" (pandas, R's arrow), "csv", or "mat" (MATLAB).
for path in export.write(tables, out, "csv"):
    print("wrote", path)
