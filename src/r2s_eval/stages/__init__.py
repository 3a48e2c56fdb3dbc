"""Thin command-line entry points, one per pipeline stage (`python -m r2s_eval.stages.<stage>`).

Each parses its inputs, outputs and JSON config slice, makes one call into its package and
writes what it returns. The library never imports Snakemake; these modules are what the Snakemake
rules run. A stage module is named after its rule (``stages/replay.py`` runs the rule ``replay``
and calls ``r2s_eval.replay``); every other module of the package has a name of its own.
"""

import os

# Stages never download: a missing local file must be an error naming it, not a hub request.
for _var in ("HF_HUB_OFFLINE", "HF_DATASETS_OFFLINE", "TRANSFORMERS_OFFLINE"):
    os.environ[_var] = "1"
