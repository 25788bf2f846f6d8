"""The data layer below the experiments, the discrepancy workflow and control: the dataset format
(:mod:`twin.data.dataset`), the predictor run over a dataset (:mod:`twin.data.prediction`) and the
least-squares parameter fit (:mod:`twin.data.fitting`). Nothing here imports a layer above it."""
