"""Layer 6, `reporting`: tables, figures and readings from scored runs: table files (`tables`),
figures (`plots`), the paper's tables and their comparison with the paper (`paper_tables`),
the paper's claims checked (`claims`), example frames for the notebooks (`rendering`).

Imports the layers above it only.
"""
