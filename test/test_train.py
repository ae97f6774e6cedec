# Copyright 2026 physdyn_ros maintainers
#
# Licensed under the Apache License, Version 2.0 (the "License");
# you may not use this file except in compliance with the License.
# You may obtain a copy of the License at
#
#     http://www.apache.org/licenses/LICENSE-2.0
#
# Unless required by applicable law or agreed to in writing, software
# distributed under the License is distributed on an "AS IS" BASIS,
# WITHOUT WARRANTIES OR CONDITIONS OF ANY KIND, either express or implied.
# See the License for the specific language governing permissions and
# limitations under the License.
"""`physdyn train` on a tiny real dataset: learning, exact resume, determinism, DDP (2 CPU processes, gloo),
and `physdyn evaluate` on the result."""
from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest
import torch

from conftest import PYTHON, ROOT
from learn_support import random_checkpoint, tiny_config, tiny_dataset
from physdyn_ros.learn.checkpoint import CheckpointError, load_checkpoint
from physdyn_ros.learn.train import train


def log(run: Path) -> list[dict]:
    return [json.loads(line) for line in (run / "train_log.jsonl").read_text().splitlines()]


def weights(path: Path) -> dict[str, torch.Tensor]:
    return load_checkpoint(path)["model"]


def same_weights(a: Path, b: Path) -> bool:
    wa, wb = weights(a), weights(b)
    return wa.keys() == wb.keys() and all(torch.equal(wa[k], wb[k]) for k in wa)


@pytest.fixture(scope="module")
def overfit_run(tmp_path_factory) -> Path:
    """A handful of training simulations, many passes: the loss must fall a lot."""
    out = tmp_path_factory.mktemp("overfit") / "run"
    cfg = tiny_config(data={"max_train_sims": 6},
                      train={"epochs": 250, "batch_size": 6, "val_every": 250, "lr": 0.01, "lr_decay_every": 10**9})
    summary = train(cfg, tiny_dataset(), out, progress=False)
    assert summary["epochs_done"] == 250 and summary["stopped"] is None
    return out


def test_loss_falls_and_a_handful_of_sequences_is_overfit(overfit_run):
    records = log(overfit_run)
    first, last = records[0]["train_total"], np.mean([r["train_total"] for r in records[-5:]])
    assert np.isfinite(last) and last < 0.4 * first, (first, last)
    assert all(np.isfinite(r["train_total"]) for r in records)
    for name in ("checkpoint_last.pt", "checkpoint_best.pt", "model_best.pt", "config.yaml"):
        assert (overfit_run / name).is_file()
    best = load_checkpoint(overfit_run / "model_best.pt")
    assert best["optimizer"] is None and best["model_id"].startswith("tiny-")
    assert best["dataset"]["manifest"]["format"] == "physdyn-dataset"
    assert set(best["normalization"]) == {"vel", "angvel", "d_vel", "d_angvel", "d_pos", "d_rot", "cloud"}


def test_resume_continues_exactly(tmp_path):
    cfg = tiny_config(data={"max_train_sims": 24}, train={"epochs": 3, "batch_size": 8, "val_rollout_horizon": 10})
    straight = train(cfg, tiny_dataset(), tmp_path / "a", progress=False)
    # Stop after every single batch (a time limit hit mid-epoch) and resume until done.
    run_b, calls = tmp_path / "b", 0
    summary = train(cfg, tiny_dataset(), run_b, time_limit=1e-9, progress=False)
    while summary["stopped"] is not None:
        calls += 1
        summary = train(cfg, tiny_dataset(), run_b, resume=str(run_b / "checkpoint_last.pt"), time_limit=1e-9,
                        progress=False)
    assert calls >= 8 and summary["step"] == straight["step"] == 9
    assert same_weights(tmp_path / "a" / "checkpoint_last.pt", run_b / "checkpoint_last.pt")
    a, b = load_checkpoint(tmp_path / "a" / "checkpoint_last.pt"), load_checkpoint(run_b / "checkpoint_last.pt")
    assert a["scheduler"] == b["scheduler"]
    sa, sb = a["optimizer"]["state"], b["optimizer"]["state"]
    assert all(torch.equal(sa[k]["exp_avg_sq"], sb[k]["exp_avg_sq"]) for k in sa)
    va = [{k: v for k, v in r.items() if k.startswith("val_")} for r in log(tmp_path / "a")]
    vb = [{k: v for k, v in r.items() if k.startswith("val_")} for r in log(run_b)]
    assert va == vb


def test_training_is_deterministic_given_the_seed(tmp_path):
    cfg = tiny_config(data={"max_train_sims": 16}, train={"epochs": 1, "batch_size": 8, "val_rollout_horizon": 0})
    train(cfg, tiny_dataset(), tmp_path / "a", progress=False)
    train(cfg, tiny_dataset(), tmp_path / "b", progress=False)
    assert same_weights(tmp_path / "a" / "checkpoint_last.pt", tmp_path / "b" / "checkpoint_last.pt")
    cfg["train"]["seed"] = 1
    train(cfg, tiny_dataset(), tmp_path / "c", progress=False)
    assert not same_weights(tmp_path / "a" / "checkpoint_last.pt", tmp_path / "c" / "checkpoint_last.pt")


def test_closed_loop_training_runs(tmp_path):
    cfg = tiny_config(data={"max_train_sims": 16},
                      train={"epochs": 1, "batch_size": 8, "rollout_fraction": 1.0, "val_rollout_horizon": 0})
    summary = train(cfg, tiny_dataset(), tmp_path / "r", progress=False)
    rec = log(tmp_path / "r")[-1]
    assert summary["step"] == 2 and np.isfinite(rec["train_total"]) and np.isfinite(rec["val_closed_loss"])


class _Result:
    def __init__(self, returncode: int, stdout: str, stderr: str) -> None:
        self.returncode, self.stdout, self.stderr = returncode, stdout, stderr


def _cli(capsys, *args: str) -> _Result:
    """`physdyn ARGS` in this process (the same entry point as the console script, without the start-up cost)."""
    from physdyn_ros.cli import main

    capsys.readouterr()
    code = main(list(args))
    out = capsys.readouterr()
    return _Result(code, out.out, out.err)


def _write_config(path: Path, cfg: dict) -> Path:
    import yaml

    path.write_text(yaml.safe_dump({k: cfg[k] for k in ("model", "loss", "train", "data")}))
    return path


def test_ddp_two_cpu_processes_gloo(tmp_path):
    """torchrun with 2 processes on the gloo backend completes and learns like a single process."""
    cfg = tiny_config(data={"max_train_sims": 32},
                      train={"epochs": 3, "batch_size": 8, "val_rollout_horizon": 10, "lr": 0.01})
    conf = _write_config(tmp_path / "tiny.yaml", cfg)
    env = dict(os.environ, OMP_NUM_THREADS="1")
    run = subprocess.run([PYTHON, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node", "2",
                          "-m", "physdyn_ros.cli", "train", "--config", str(conf), "--data", str(tiny_dataset()),
                          "--out", str(tmp_path / "ddp"), "--no-progress"],
                         cwd=ROOT, capture_output=True, text=True, timeout=300, env=env)
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-3000:]
    summary = json.loads(run.stdout.strip().splitlines()[-1])
    # 32 simulations / (2 processes x 4 windows) = 4 steps per epoch
    assert summary["epochs_done"] == 3 and summary["step"] == 12
    records = log(tmp_path / "ddp")
    assert len(records) == 3 and all(np.isfinite(r["val_loss"]) for r in records)
    single = train(cfg, tiny_dataset(), tmp_path / "single", progress=False)
    single_val = log(tmp_path / "single")[-1]["val_loss"]
    assert single["step"] == 12
    assert records[-1]["val_loss"] < records[0]["train_total"]
    assert abs(records[-1]["val_loss"] - single_val) < 0.25 * single_val


def test_cli_refuses_to_overwrite_and_checks_resume(tmp_path, capsys):
    cfg = tiny_config(data={"max_train_sims": 8}, train={"epochs": 1, "batch_size": 8, "val_rollout_horizon": 0})
    conf = _write_config(tmp_path / "tiny.yaml", cfg)
    data, out = str(tiny_dataset()), str(tmp_path / "run")
    first = _cli(capsys, "train", "--config", str(conf), "--data", data, "--out", out, "--no-progress")
    assert first.returncode == 0, first.stderr[-2000:]
    again = _cli(capsys, "train", "--config", str(conf), "--data", data, "--out", out)
    assert again.returncode == 2 and "--resume" in again.stderr
    more = _cli(capsys, "train", "--data", data, "--out", out, "--resume", "--max-epochs", "2", "--no-progress")
    assert more.returncode == 0 and json.loads(more.stdout.strip().splitlines()[-1])["epochs_done"] == 2
    other = _write_config(tmp_path / "other.yaml", tiny_config(model={"hidden_size": 16}))
    bad = _cli(capsys, "train", "--config", str(other), "--data", data, "--out", out, "--resume")
    assert bad.returncode == 2 and "model" in bad.stderr and "differs" in bad.stderr
    missing = _cli(capsys, "train", "--data", data, "--out", out, "--resume", str(tmp_path / "nope.pt"))
    assert missing.returncode == 2 and "does not exist" in missing.stderr


def test_resume_accepts_a_checkpoint_written_before_a_model_key_existed(tmp_path, capsys):
    """A run saved before a model key existed (its stored model section lacks the key) resumes, with and without
    --config: the key takes its default ("its model config differs" before)."""
    cfg = tiny_config(data={"max_train_sims": 8}, train={"epochs": 1, "batch_size": 8, "val_rollout_horizon": 0})
    conf = _write_config(tmp_path / "tiny.yaml", cfg)
    data, out = str(tiny_dataset()), tmp_path / "run"
    first = _cli(capsys, "train", "--config", str(conf), "--data", data, "--out", str(out), "--no-progress")
    assert first.returncode == 0, first.stderr[-2000:]
    last = out / "checkpoint_last.pt"
    ckpt = torch.load(last, weights_only=True)
    del ckpt["config"]["model"]["com_head"]  # as a version before the centre-of-mass head wrote it
    torch.save(ckpt, last)
    for extra in ([], ["--config", str(conf)]):
        more = _cli(capsys, "train", *extra, "--data", data, "--out", str(out), "--resume", "--max-epochs",
                    str(2 + len(extra) // 2), "--no-progress")
        assert more.returncode == 0, more.stderr[-2000:]


def test_evaluate_cli_writes_reports(overfit_run, tmp_path, capsys):
    mlp = random_checkpoint(tmp_path / "mlp.pt", cell="mlp")
    out = tmp_path / "eval"
    run = _cli(capsys, "evaluate", "--checkpoint", str(overfit_run / "model_best.pt"), "--data", str(tiny_dataset()),
               "--horizon", "40", "--mlp-checkpoint", str(mlp), "--out", str(out), "--threads", "1")
    assert run.returncode == 0, run.stderr[-3000:]
    report = json.loads((out / "metrics.json").read_text())
    overall = report["results"]["overall"]
    assert {"model", "mlp", "analytic", "pybullet_mu-20%", "pybullet_mu+20%"} <= set(overall)
    m = overall["model"]
    assert set(m["single_step"]) == {"v", "w", "p", "angle", "axis"}
    assert m["final_pos_cm"]["median"] is not None and m["final_pos_cm"]["p90"] >= m["final_pos_cm"]["median"]
    assert len(m["pos_cm_vs_time_median"]) == 41
    assert set(m["topple"]) >= {"accuracy", "precision", "recall", "f1"}
    assert set(report["results"]["per_category"]) == {"box", "cylinder", "bottle"} & set(
        report["results"]["per_category"])
    assert (out / "rollout_error.png").stat().st_size > 1000
    assert "| overall | model |" in (out / "metrics.md").read_text()
    # friction-generalisation style run: observed steps in, learned models only
    steps = _cli(capsys, "evaluate", "--checkpoint", str(overfit_run / "model_best.pt"), "--data", str(tiny_dataset()),
                 "--horizon", "40", "--steps-in", "4", "--baselines", "--out", str(tmp_path / "e4"))
    assert steps.returncode == 0, steps.stderr[-2000:]
    rep4 = json.loads((tmp_path / "e4" / "metrics.json").read_text())
    assert rep4["steps_in"] == 4 and set(rep4["results"]["overall"]) == {"model"}
    # partial depth-camera views, against the object that stays still
    part = _cli(capsys, "evaluate", "--checkpoint", str(overfit_run / "model_best.pt"), "--data", str(tiny_dataset()),
                "--horizon", "40", "--partial", "1", "--baselines", "still", "--out", str(tmp_path / "ep"))
    assert part.returncode == 0, part.stderr[-2000:]
    rep = json.loads((tmp_path / "ep" / "metrics.json").read_text())
    assert rep["partial_views"] == 1.0 and set(rep["results"]["overall"]) == {"model", "still"}
    assert rep["results"]["overall"]["still"]["final_pos_cm"]["median"] > 0  # the pushed objects do move
    assert rep["results"]["overall"]["model"] != overall["model"]  # other clouds, other predictions


def test_bad_data_and_config_give_clear_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="does not exist|not a dataset"):
        train(tiny_config(), tmp_path / "no-data", tmp_path / "run", progress=False)
    with pytest.raises(ValueError, match="unknown model config keys"):
        tiny_config(model={"hidden": 3})
    with pytest.raises(ValueError, match="unknown categories"):
        train(tiny_config(data={"categories": ["teapot"]}), tiny_dataset(), tmp_path / "run2", progress=False)
    with pytest.raises(CheckpointError):
        (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
        train(tiny_config(), tiny_dataset(), tmp_path / "run3", resume=str(tmp_path / "junk.pt"), progress=False)


def test_fine_tune_starts_from_the_init_checkpoint(overfit_run, tmp_path):
    """--init: a new run whose first weights and normalisation are the pretrained ones."""
    init = overfit_run / "checkpoint_best.pt"
    before = load_checkpoint(init)
    cfg = tiny_config(data={"max_train_sims": 6}, train={"epochs": 1, "batch_size": 6, "lr": 1e-9})
    train(cfg, tiny_dataset(), tmp_path / "ft", progress=False, init=str(init))
    after = load_checkpoint(tmp_path / "ft" / "checkpoint_last.pt")
    assert after["normalization"] == before["normalization"]
    # one epoch at a negligible learning rate: still (almost exactly) the pretrained weights, not a fresh init
    for k, w in before["model"].items():
        assert torch.allclose(after["model"][k].float(), w.float(), atol=1e-5), k
    first = log(tmp_path / "ft")[0]
    assert first["train_total"] < 0.5 * log(overfit_run)[0]["train_total"]  # starts where the init left off
    with pytest.raises(CheckpointError, match="model config differs"):
        train(tiny_config(model={"hidden_size": 8}), tiny_dataset(), tmp_path / "ft2", progress=False, init=str(init))
    with pytest.raises(ValueError, match="cannot be combined with --resume"):
        train(cfg, tiny_dataset(), tmp_path / "ft3", resume=str(init), init=str(init), progress=False)


def test_set_reads_numbers_as_numbers():
    """--set train.lr=1e-4 reached torch's Adam as the string '1e-4' (YAML 1.1 wants a dot in a float) and
    failed there with a TypeError."""
    from physdyn_ros.learn.config import apply_overrides

    raw: dict = {}
    apply_overrides(raw, ["train.lr=1e-4", "train.epochs=3", "model.cell=lstm", "data.categories=[box, mug]"])
    assert raw == {"train": {"lr": 1e-4, "epochs": 3}, "model": {"cell": "lstm"},
                   "data": {"categories": ["box", "mug"]}}
    assert isinstance(raw["train"]["lr"], float) and isinstance(raw["train"]["epochs"], int)
    apply_overrides(raw, ["model.name=nan", "model.name2=1_000", "train.lr=-2.5E-3"])
    assert raw["model"]["name"] == "nan" and raw["model"]["name2"] == 1000 and raw["train"]["lr"] == -2.5e-3


def test_a_fine_tune_may_swap_the_physics_prior_and_nothing_else():
    """The prior has no weights: a fine-tune may move a sliding-prior model to the coupled prior or
    another friction; a checkpoint written before newer config keys existed compares with their defaults."""
    from physdyn_ros.learn.train import _same_weights

    base = {"name": "m", "geometry": True, "prior": "sliding", "hidden_size": 32}
    assert _same_weights(base, {**base, "prior": "coupled", "prior_friction": 0.4})
    assert _same_weights(base, {**base, "topple_head": False, "topple_members": 5})
    assert not _same_weights(base, {**base, "hidden_size": 16})
    assert not _same_weights({**base, "prior": "none"}, {**base, "prior": "coupled"})


def test_shipped_options_train_the_skip_path_and_the_loss_falls(tmp_path):
    """input_skip + w_abs (config/model_default.yaml): the zero-initialised skip learns, the loss falls."""
    cfg = tiny_config(model={"input_skip": True}, loss={"w_abs": 2.0, "relative_to": "target", "eps": 0.1},
                      data={"max_train_sims": 6},
                      train={"epochs": 40, "batch_size": 6, "val_every": 40, "lr": 0.01, "rollout_fraction": 0.5})
    train(cfg, tiny_dataset(), tmp_path / "r", progress=False)
    records = log(tmp_path / "r")
    assert records[-1]["train_abs"] < 0.7 * records[0]["train_abs"], (records[0], records[-1])
    skip = load_checkpoint(tmp_path / "r" / "model_best.pt")["model"]["skip.weight"]
    assert skip.shape == (13, 6) and skip.abs().max() > 1e-3
