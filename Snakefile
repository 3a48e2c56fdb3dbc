# r2s-eval: teleop data -> calibrated sim -> policies -> rollouts -> judge -> ranking.
# Stages live in workflow/rules/ (one file each); configuration is Hydra's, under conf/.
#   snakemake -j 2 reports/realsim_table.tex                       (default experiment: demo)
#   snakemake -j 2 reports/realsim_table.tex --config experiment=smoke
#   snakemake -j 2 ... --config overrides='[stats.n_boot=500]'     (any Hydra override)
#   snakemake -j 2 reports                                         (every table and figure)
#   snakemake -j 2 reports/libero_table.tex --config experiment=libero_smoke   (the LIBERO setting)

include: "workflow/rules/common.smk"


# The rollouts and their reference: LIBERO's (experiments that compose conf/libero), or the
# real-to-sim chain (teleop data, calibration, replay, fine-tuning, sim and real rollouts).
if LIBERO:

    include: "workflow/rules/libero.smk"

else:

    include: "workflow/rules/real.smk"
    include: "workflow/rules/ingest.smk"
    include: "workflow/rules/init.smk"
    include: "workflow/rules/replay.smk"
    include: "workflow/rules/train.smk"
    include: "workflow/rules/rollout.smk"


include: "workflow/rules/judge.smk"
include: "workflow/rules/compare.smk"
include: "workflow/rules/fit.smk"
include: "workflow/rules/report.smk"


if not LIBERO:

    include: "workflow/rules/fidelity.smk"  # the same checkpoint in both worlds, the ablation
    include: "workflow/rules/resolution.smk"  # each judge's resolution over the planted kinds

include: "workflow/rules/annotate.smk"


rule all:
    input:
        REPORTS,  # every table and figure (workflow/rules/report.smk); alone: `snakemake reports`
        "results/annotate/set.parquet",  # the human annotation set (workflow/rules/annotate.smk)
        "results/init/error_summary.json" if TWIN else [],
        "results/world/report.json" if TWIN else [],  # per-task teleop, pose error, replay
