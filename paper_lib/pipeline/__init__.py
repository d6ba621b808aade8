"""Layer 7, `pipeline`: the stages DVC runs and the commands a reader types.

- `config`: params.yaml's run profiles (`python -m paper_lib.pipeline.config use tiny`).
- `layout`: where every artifact lives under results/<profile>/, stage by stage (the paths dvc.yaml names).
- `stages`: the train and collect stages of one run (`python -m paper_lib.pipeline.stages collect ...`).
- `run_results`: a run's evaluation and score files, and the CLI that writes them.
- `status`, `reproduce`, `verify`: what exists, the rebuild (`make reproduce`), the recomputation check.
- `notebook_run`: papermill with the run metadata stripped; `evaluate_agent`: score any agent end to end.

Imports the layers above it only.
"""
