"""Layer 8, `experiments`: studies beyond the main matrix, each on top of the pipeline:
independently trained ensembles (`ensembles`, `ensembles_report`), spawning in perturbed
physics (`spawn`), how much value uncertainty is a low value (`value_level`), and the recipe
probes that settled the agents' hyperparameters (`recipe_probes`)."""
