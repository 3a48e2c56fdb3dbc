"""Thin command-line entry points, one per pipeline stage (`python -m r2s_eval.stages.<stage>`).

Each parses its inputs, outputs and JSON config slice, then calls library code. The library
never imports Snakemake; these modules are what the Snakemake rules run.
"""
