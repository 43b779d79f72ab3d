"""Retrieval stage: score prior windows by their skill latents' distance to the target's, keep the closest.

Modules, in data-flow order:
- `settings`: `RetrievalSettings` (the paper's knobs, A.4 modes, opt-in extras) and `ABLATIONS`.
- `kernels`: `NearestTarget`, chunked L2 / symmetric-KL distance to the nearest target latent in bounded memory.
- `select`: the r closest (float64-exact at the cut), and the greedy walk behind suppression / quota options.
- `engine`: `select_windows`, scores + selection on latents.
- `api`: `retrieve`, checkpoint + datasets -> encoded windows -> `RetrievalResult` file (+ report).
- `schema`: `RetrievalResult`, the file stage 2 reads.
- `report`: summary JSON, plots, retrieval precision against primitive labels.
- `cli`: the `skillret-retrieve` command.
"""
