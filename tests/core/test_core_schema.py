"""The config schema: every shipped experiment validates; wrong keys fail naming key and file."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import pytest

from r2s_eval.config import compose_config
from r2s_eval.errors import ConfigError
from r2s_eval.schema import known_paths, validate_config

CONF = Path(__file__).resolve().parents[2] / "conf"


@pytest.fixture
def conf_copy(tmp_path) -> Path:
    """A scratch copy of conf/ to break."""
    return Path(shutil.copytree(CONF, tmp_path / "conf"))


def _edit(path: Path, old: str, new: str) -> None:
    text = path.read_text()
    assert old in text, f"{old!r} not in {path}"
    path.write_text(text.replace(old, new, 1))


@pytest.mark.parametrize("experiment", ["smoke", "demo", "paper", "fidelity"])
def test_every_experiment_composes_and_validates(experiment):
    cfg = compose_config(CONF, experiment)
    validate_config(cfg)  # the returned dict is the validated one; checking it again is a no-op
    assert {"tasks", "seed", "suite", "world", "real", "policies", "judges", "report"} <= set(cfg)


def test_smoke_operator_is_tidy():
    # The example: smoke's tidy operator used to sit under calib, where nothing read it.
    operator = compose_config(CONF, "smoke")["teleop"]["operator"]
    assert operator == {"pause_prob": 0.0, "overshoot_prob": 0.0, "regrasp_prob": 0.0}


def test_misplaced_key_in_experiment_file_names_key_and_file(conf_copy):
    _edit(conf_copy / "experiment" / "smoke.yaml", "calib:\n",
          "calib:\n  operator: {pause_prob: 0.0}\n")
    with pytest.raises(ConfigError) as err:
        compose_config(conf_copy, "smoke")
    message = str(err.value)
    assert "calib.operator (set in conf/experiment/smoke.yaml) is not a key of calib" in message
    assert "did you mean teleop.operator?" in message


def test_unknown_key_in_group_file_names_that_file(conf_copy):
    _edit(conf_copy / "stats" / "default.yaml", "n_boot: 1000\n", "n_boot: 1000\nnboot: 5\n")
    with pytest.raises(ConfigError, match=r"stats\.nboot \(set in conf/stats/default\.yaml\) .*did you mean stats\.n_boot\?"):
        compose_config(conf_copy, "demo")


def test_missing_key_names_the_file_that_owns_it(conf_copy):
    _edit(conf_copy / "replay" / "default.yaml", "max_attempts: 9\n", "")
    with pytest.raises(ConfigError, match=r"replay\.max_attempts \(expected in conf/replay/default\.yaml\) is missing"):
        compose_config(conf_copy, "demo")


@pytest.mark.parametrize("override", ["stats.n_bot=3", "+stats.n_bot=3"])
def test_unknown_override_fails_naming_it(override):
    with pytest.raises(ConfigError) as err:
        compose_config(CONF, "smoke", [override])
    message = str(err.value)
    assert f"stats.n_bot (set by the command-line override '{override}') is not a key of stats" in message
    assert "did you mean stats.n_boot?" in message


def test_override_of_an_unset_entry_key_says_how_to_add_it():
    with pytest.raises(ConfigError, match=r"judges\.kinematic\.concurrency .* write '\+judges\.kinematic\.concurrency=2'"):
        compose_config(CONF, "smoke", ["judges.kinematic.concurrency=2"])


def test_wrong_type_fails_naming_the_key():
    with pytest.raises(ConfigError, match=r"rollout\.max_duration_s \(set by the command-line override .*\) must be a number, got 'abc'"):
        compose_config(CONF, "smoke", ["rollout.max_duration_s=abc"])
    with pytest.raises(ConfigError, match=r"stats\.ci_level .* must be in \(0, 1\)"):
        compose_config(CONF, "smoke", ["stats.ci_level=1.5"])
    with pytest.raises(ConfigError, match=r"world\.cameras .* records \['cam9'\], which the rig \[.*\] does not place"):
        compose_config(CONF, "smoke", ["world.cameras=[head_left,cam9]"])


def test_wrong_type_in_a_file_names_the_file(conf_copy):
    _edit(conf_copy / "teleop" / "default.yaml", "keep_failed: false", "keep_failed: sometimes")
    with pytest.raises(ConfigError, match=r"teleop\.keep_failed \(set in conf/teleop/default\.yaml\) must be true or false"):
        compose_config(conf_copy, "demo")


def test_open_entries_are_checked_by_their_owners():
    with pytest.raises(ConfigError, match=r"policies\.act\.stepz \(set by .*\): unknown policy config key"):
        compose_config(CONF, "smoke", ["+policies.act.stepz=3"])
    with pytest.raises(ConfigError, match=r"judges\.video\.swap_shar .*: video judge: unknown config keys"):
        compose_config(CONF, "demo", ["+judges.video.swap_shar=0.1"])
    with pytest.raises(ConfigError, match=r"teleop\.operator\.pause_prb .*did you mean teleop\.operator\.pause_prob\?"):
        compose_config(CONF, "smoke", ["+teleop.operator.pause_prb=0.1"])
    with pytest.raises(ConfigError, match=r"suite\.cup_on_plat .*did you mean 'cup_on_plate'\?"):
        compose_config(CONF, "smoke", ["+suite.cup_on_plat.init_regions=null"])


def test_recording_video_settings_are_checked():
    with pytest.raises(ConfigError, match=r"teleop\.video\.codec .*did you mean teleop\.video\.vcodec\?"):
        compose_config(CONF, "smoke", ["+teleop.video.codec=h264"])
    with pytest.raises(ConfigError, match=r"replay\.video\.crf .*must be a number"):
        compose_config(CONF, "smoke", ["replay.video.crf=high"])
    assert compose_config(CONF, "smoke", ["replay.video.vcodec=libsvtav1", "replay.video.preset=12"])["replay"]["video"] \
        == {"vcodec": "libsvtav1", "preset": 12, "crf": 18}


def test_judge_video_rate_must_divide_the_control_rate():
    with pytest.raises(ConfigError, match=r"rollout\.video_fps .*must divide the control rate \(10 Hz\)"):
        compose_config(CONF, "smoke", ["rollout.video_fps=3"])


def test_the_receding_horizon_has_one_owner():
    """How many actions run before the next query is the evaluation's, never a policy's."""
    with pytest.raises(ConfigError, match=r"policies\.act\.n_action_steps .*receding horizon, rollout\.horizon\.execute"):
        compose_config(CONF, "smoke", ["+policies.act.n_action_steps=5"])
    for experiment in ("smoke", "demo", "paper"):
        cfg = compose_config(CONF, experiment)
        assert not [name for name, p in cfg["policies"].items() if "n_action_steps" in p]
        assert cfg["rollout"]["horizon"] == {"chunk": 25, "execute": 5}


def test_the_horizon_rule_is_checked_at_composition():
    with pytest.raises(ConfigError, match=r"rollout\.horizon .*execute \(30\) <= rollout\.horizon\.chunk \(25\)"):
        compose_config(CONF, "smoke", ["rollout.horizon.execute=30"])
    # Every trained candidate of smoke predicts 25 actions per call: a longer chunk cannot be used.
    with pytest.raises(ConfigError, match=r"rollout\.horizon .*chunk \(30\) <= 25, the most actions policies\.\w+ "
                                          r"predicts per call"):
        compose_config(CONF, "smoke", ["rollout.horizon.chunk=30"])
    assert compose_config(CONF, "smoke", ["rollout.horizon.execute=25"])["rollout"]["horizon"]["execute"] == 25


@pytest.mark.parametrize(("old", "new"), [("chunk_size", "horizon.chunk"), ("n_action_steps", "horizon.execute")])
def test_the_old_horizon_keys_name_their_new_names(conf_copy, old, new):
    renamed = rf"was renamed rollout\.{re.escape(new)}$"
    with pytest.raises(ConfigError, match=rf"rollout\.{old} \(set by the command-line override .*\) {renamed}"):
        compose_config(CONF, "smoke", [f"rollout.{old}=5"])
    # In an experiment file the same key is named with its file.
    _edit(conf_copy / "experiment" / "smoke.yaml", "rollout:\n", f"rollout:\n  {old}: 5\n")
    with pytest.raises(ConfigError, match=rf"rollout\.{old} \(set in conf/experiment/smoke\.yaml\) {renamed}"):
        compose_config(conf_copy, "smoke")


@pytest.mark.parametrize("group", ["teleop", "rollout"])
def test_an_episode_length_in_steps_names_its_length_in_seconds(group):
    with pytest.raises(ConfigError, match=rf"{group}\.max_steps \(set by the command-line override .*\) was renamed "
                                          rf"{group}\.max_duration_s \(seconds; the world's robot\.control_hz makes them steps\)"):
        compose_config(CONF, "smoke", [f"{group}.max_steps=450"])


def test_keys_set_by_a_group_option_it_builds_on_are_located(conf_copy):
    # demo's judges=audited extends judges/default.yaml; a bad key there is found there.
    _edit(conf_copy / "judges" / "default.yaml", "backend: video", "backend: video\n  blurr_px: 2")
    with pytest.raises(ConfigError, match=r"judges\.video\.blurr_px \(set in conf/judges/default\.yaml\)"):
        compose_config(conf_copy, "demo")


def test_cross_group_contradictions():
    with pytest.raises(ConfigError, match=r"calib\.camera .* must be one of the recorded world\.cameras"):
        compose_config(CONF, "smoke", ["calib.camera=head_right"])
    with pytest.raises(ConfigError, match=r"policies\.act\.image_keys .* \['wrist_left'\]"):
        compose_config(CONF, "smoke", ["policies.act.image_keys=[observation.images.wrist_left]"])
    with pytest.raises(ConfigError, match=r"report\.judge_audit\.planted_order .* names \['act_subset'\]"):
        compose_config(CONF, "smoke", ["~policies.act_subset"])
    with pytest.raises(ConfigError, match=r"report\.judge_audit\.planted_order .* names \['act_short'\]"):
        compose_config(CONF, "demo", ["~policies.act_short"])


def test_an_experiment_with_another_worlds_cameras_is_named_as_the_cause():
    # smoke records the bundled world's head_left; on the SO-101 no camera would be fixed, but the
    # derived settings (calib.camera, ...) are not the cause and would not fix it.
    with pytest.raises(ConfigError) as err:
        compose_config(CONF, "smoke", ["world=so101"])
    lines = _problem_lines(err)
    assert lines[0].startswith("world.cameras (set in conf/experiment/smoke.yaml) records ['head_left'], which the "
                               "rig ['front', 'wrist'] does not place; conf/experiment/smoke.yaml names the cameras of "
                               "another world: override world.cameras for this world (e.g. world.cameras=[front,wrist])")
    assert "an experiment of your own" in lines[0]
    assert not any(line.startswith(("calib.camera", "rollout.video_camera")) for line in lines), lines
    assert "set calib.camera" not in str(err.value)
    with pytest.raises(ConfigError) as err:
        compose_config(CONF, "smoke", ["world=so101", "world.cameras=[head_left]"])
    assert _problem_lines(err)[0].startswith("world.cameras (set by the command-line override "
                                             "'world.cameras=[head_left]') records ['head_left']")
    assert "set calib.camera" not in str(err.value)


def test_a_missing_group_option_is_a_config_error():
    with pytest.raises(ConfigError, match="judges/vlm"):
        compose_config(CONF, "smoke", ["judges=vlm"])


def test_every_group_has_a_schema():
    top = {p for p in known_paths() if "." not in p}
    assert {"suite", "world", "real", "teleop", "ingest", "calib", "replay", "policies", "rollout", "judges",
            "compare", "stats", "report", "annotate", "fidelity", "stability", "resolution", "tasks", "seed",
            "libero"} == top


def _problem_lines(err: pytest.ExceptionInfo) -> list[str]:
    message = str(err.value)
    return [line.removeprefix("  - ") for line in message.splitlines()[1:]] if "problems:" in message else [message]


def test_every_bad_override_is_listed_one_line_each():
    # Hydra refuses an unknown key at the first one; each is set aside and the rest composed,
    # so the unknown keys and the wrong values are all reported together.
    overrides = ["stats.nboot=1", "compare.nosuch=2", "stats.ci_level=2", "policies.act.steps=abc"]
    with pytest.raises(ConfigError) as err:
        compose_config(CONF, "smoke", overrides)
    lines = _problem_lines(err)
    assert str(err.value).startswith("4 configuration problems:")
    assert len(lines) == 4
    for override in overrides:
        key = override.split("=")[0]
        assert sum(line.startswith(f"{key} (set by the command-line override '{override}')") for line in lines) == 1, lines
    assert any("did you mean stats.n_boot?" in line for line in lines)


@pytest.mark.parametrize(("override", "message"), [
    ("policies.act.steps=abc", "must be an integer, got 'abc' (str)"),
    ("policies.act.steps=-5", "must be in [1, inf], got -5"),
    ("policies.act.lr=0", "must be in (0, inf], got 0"),
    ("+policies.act.episodes_fraction=1.5", "must be in (0, 1], got 1.5"),
    ("policies.act.image_size=[32]", "must be a list of 2 values, got [32]"),
    ("+policies.act.scheduler=linear", "must be one of ['constant', 'cosine'], got 'linear'"),
    ("policies.act.image_keys=[]", "must not be empty"),
])
def test_trained_policy_entry_is_typed_like_the_groups(override, message):
    key = override.lstrip("+").split("=")[0]
    with pytest.raises(ConfigError) as err:
        compose_config(CONF, "smoke", [override])
    assert str(err.value) == f"{key} (set by the command-line override '{override}') {message}"


def test_external_policy_entry_is_typed_like_the_groups():
    add = "+policies.lab={type:server,port:99999,reply_timeout_s:abc}"
    with pytest.raises(ConfigError) as err:
        compose_config(CONF, "smoke", [add])
    lines = _problem_lines(err)
    assert len(lines) == 2
    assert any(line.startswith("policies.lab.port (") and "must be in [1, 65535], got 99999" in line for line in lines)
    assert any(line.startswith("policies.lab.reply_timeout_s (") and "must be a number, got 'abc'" in line for line in lines)


def test_policy_schemas_type_every_key_their_owners_accept():
    # The schema types the keys; their owners hold the defaults: the two must list the same keys.
    import dataclasses

    from r2s_eval import policy_sources as sources
    from r2s_eval.policies.types import TOP_LEVEL_DEFAULTS
    from r2s_eval.schema import CheckpointPolicy, ServerPolicy, TrainedPolicy

    def names(cls):
        return {f.name for f in dataclasses.fields(cls)}

    assert names(TrainedPolicy) == set(TOP_LEVEL_DEFAULTS)
    assert names(CheckpointPolicy) == {*sources._COMMON, *sources._PER_TYPE["checkpoint"]}
    assert names(ServerPolicy) == {*sources._COMMON, *sources._PER_TYPE["server"]}


def test_a_lab_dataset_or_trials_csv_that_is_not_there_names_the_setting(tmp_path):
    from r2s_eval.config import missing_inputs

    data, trials = tmp_path / "my_teleop", tmp_path / "trials.csv"
    cfg = compose_config(CONF, "smoke", ["real=dataset", f"real.dataset_root={data}", f"real.reference_csv={trials}",
                                         "fidelity.ablation.policies=[]", "stability.repetitions=0"])
    with pytest.raises(ConfigError) as err:
        missing_inputs(cfg)
    assert _problem_lines(err) == [
        f"real.dataset_root = {data}: no such folder (a LeRobotDataset v3 folder)",
        f"real.reference_csv = {trials}: no such file (a CSV of hardware trials: policy, task, trials, successes)",
    ]
    data.mkdir()
    trials.write_text("policy,task,trials,successes\n")
    missing_inputs(cfg)  # both there: nothing to say
    missing_inputs(compose_config(CONF, "smoke"))  # the twin's own recording is made by the run


@pytest.mark.parametrize(("overrides", "message"), [
    (["fidelity.ablation.policies=[nope]"], r"fidelity.ablation.policies\[0\].*must be a candidate trained here"),
    (["fidelity.ablation.families=[colour]"], r"fidelity.ablation.families\[0\].*must be one of"),
    (["fidelity.ablation.policies=[act]", "real.source=dataset", "real.dataset_root=x", "real.reference_csv=y.csv"],
     "needs real.source twin"),
    (["+policies.act.seeds=0"], r"policies.act.seeds .*must be in \[1, inf\]"),
    (["+policies.act.seed=-1"], r"policies.act.seed .*must be in \[0, inf\]"),
    (["fidelity.sims=[calibrated]"], r"fidelity.sims\[0\].*must be one of"),
    (["fidelity.sims=[nominal,without_lens]"],
     r"fidelity.sims\[1\] .*'without_lens' takes away an answer the calibration does not give "
     r"\(calib.cameras.board.intrinsics is off\)"),
    (["fidelity.sims=[without_background]"], r"fidelity.sims\[0\].*\(calib.background.fit is off\)"),
    (["fidelity.sims=[without_shadows]"], r"fidelity.sims\[0\].*\(calib.appearance.shadows is off\)"),
    (["fidelity.ablation.alone=[lens]", "fidelity.ablation.policies=[]"], r"fidelity.ablation.alone .*needs fidelity.ablation.policies"),
    (["fidelity.ablation.alone=[focus]"], r"fidelity.ablation.alone\[0\].*must be one of"),
    (["fidelity.ablation.alone=[lens]", "fidelity.ablation.policies=[act]"],
     r"fidelity.ablation.alone\[0\] .*this twin has no 'lens' effect"),
    (["calib.joints.iterations=0"], r"calib.joints.iterations"),
])
def test_fidelity_settings_are_checked(overrides, message):
    with pytest.raises(ConfigError, match=message):
        compose_config(CONF, "smoke", overrides)


@pytest.mark.parametrize(("overrides", "message"), [
    (["stability.repetitions=1"], r"stability.repetitions .*must be 0 \(off\) or at least 2, got 1"),
    (["rollout.inits_per_task=5"], r"stability.repetitions .*2 repetitions of rollout.inits_per_task 5 leave 2 real "
                                   r"inits per task each, fewer than the 3 real trials asked"),
    (["rollout.inits_per_task=12", "rollout.real_inits_per_task=5"],
     r"2 repetitions of rollout.real_inits_per_task 5 leave 2 real inits"),
])
def test_stability_settings_are_checked(overrides, message):
    with pytest.raises(ConfigError, match=message):
        compose_config(CONF, "smoke", overrides)


def test_the_sim_may_roll_out_more_inits_than_the_real_side_of_the_repetitions():
    # Each repetition takes its share of the sim-only inits; the real blocks hold the trials asked.
    cfg = compose_config(CONF, "smoke", ["rollout.inits_per_task=12", "rollout.real_inits_per_task=6"])
    assert (cfg["rollout"]["inits_per_task"], cfg["rollout"]["real_inits_per_task"]) == (12, 6)


@pytest.mark.parametrize(("overrides", "message"), [
    (["resolution.policy=nope"], r"resolution.policy .*must name a candidate of this line-up that is not a variant"),
    (["resolution.policy=act_hesitant"], r"resolution.policy .*not a variant"),
    (["resolution.kinds=[jitter,wobble]"], r"resolution.kinds\[1\] .*must be a key of resolution.sweeps"),
    (["resolution.sweeps.jitter.levels=[0.04,0.01]"], r"resolution.sweeps.jitter.levels .*must increase"),
    (["resolution.kinds=[overshoot]", "resolution.sweeps.overshoot.levels=[0.5,1.5]"],
     r"resolution.sweeps.overshoot.levels\[1\] .*overshoot"),
    (["resolution.detect_share=0.5"], r"resolution.detect_share"),
])
def test_resolution_settings_are_checked(overrides, message):
    with pytest.raises(ConfigError, match=message):
        compose_config(CONF, "smoke", overrides)


def test_every_sweep_kind_of_the_defaults_makes_valid_variants():
    from r2s_eval.compare.resolution import sweep_levels
    from r2s_eval.policy_sources import validate_variant_cfg

    cfg = compose_config(CONF, "demo", ["resolution.policy=act",
                                        "resolution.kinds=[jitter,stops,fumbling,overshoot,late_gripper,sluggish]"])
    levels = sweep_levels(cfg["resolution"])
    assert len(levels) == 30 and len({lv.policy for lv in levels}) == 30
    for lv in levels:
        validate_variant_cfg(lv.variant("act"), lv.policy)
