"""A stage uses no more threads than its job was given (r2s_eval.utils.numerics.limit_threads)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from r2s_eval.utils.numerics import THREAD_ENV, job_threads

# A stage entry point that reports its thread pools from inside `main`, as a stage would run.
PROBE = """
import json, os, sys
import torch
from r2s_eval.stages import _cli

def main(args):
    import cv2
    print(json.dumps({"torch": torch.get_num_threads(), "cv2": cv2.getNumThreads(),
                      "env": {k: os.environ.get(k) for k in sys.argv[1].split(",")}}))

_cli.run(main, _cli.parser("probe", cfg=False), argv=[])
"""


def _probe(env: dict) -> dict:
    out = subprocess.run([sys.executable, "-c", PROBE, ",".join(THREAD_ENV)], env=env, capture_output=True,
                         text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_stage_takes_its_jobs_threads_from_the_workflow():
    # Snakemake sets OMP_NUM_THREADS to the job's threads; torch, OpenCV and every pool sized by
    # the environment (llvmpipe's rendering threads among them) follow it.
    seen = _probe({**os.environ, "OMP_NUM_THREADS": "1"})
    assert seen["torch"] == 1 and seen["cv2"] == 1
    assert seen["env"] == {k: "1" for k in THREAD_ENV}


def test_stage_outside_the_workflow_uses_the_cpus_it_may_run_on():
    env = {k: v for k, v in os.environ.items() if k not in THREAD_ENV}
    cpus = len(os.sched_getaffinity(0))
    seen = _probe(env)
    assert seen["cv2"] == cpus and seen["env"]["LP_NUM_THREADS"] == str(cpus)


@pytest.mark.parametrize("value, expected", [("3", 3), ("", None), ("0", None), ("x", None)])
def test_job_threads_reads_a_positive_count_only(monkeypatch, value, expected):
    monkeypatch.setenv("OMP_NUM_THREADS", value)
    assert job_threads() == (expected or len(os.sched_getaffinity(0)))
