"""Layer 0, `common`: what every other layer uses and nothing of the paper: atomic writes (`io`),
provenance of a run (`provenance`), checks on the DataFrames tables and plots receive (`frames`).
Imports no other paper_lib package."""
