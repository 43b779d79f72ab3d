"""Retrieval stage: score prior windows by their skill latents' distance to the target's, keep the closest.

Modules (start reading at `api.retrieve`):
- `settings`: `RetrievalSettings` (the paper's knobs and A.4 modes) and `ABLATIONS`, with their range checks.
- `api`: `retrieve`, read top to bottom: checkpoint + datasets -> encoded windows -> `select_windows` (modes on
  latents) -> `RetrievalResult` file (`data.retrieval_file`, the contract stage 2 reads) + report.
- `kernels`: `NearestTarget`, chunked L2 / symmetric-KL distance to the nearest target latent in bounded memory;
  `smallest`, the r closest (float64-exact at the cut); `Selection`.
- `report`: summary JSON, plots, retrieval precision against primitive labels.
- `cli`: the `skillret-retrieve` command.
"""
