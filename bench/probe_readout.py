"""Is it the encoder or the head? Re-fit only the output layer of a trained run, two ways.

    OMP_NUM_THREADS=1 .venv/bin/python bench/probe_readout.py --checkpoint RUN/best.pt --dataset DS \
        --category CAT [--ridge] [--sgd-steps 600 --lr 1e-4] [--fits fits.pt] [--out readout.pt]

The encoder and hidden layers stay frozen (evaluation mode); only ``out`` (the linear map from the
last hidden layer to the template parameters) changes. Validation L_Ch (one view, as ``fit``
selects ``best.pt``) is printed for the run's own head and for each re-fit:

- ``--sgd-steps N``: N more steps of the run's training loss on the head alone, at ``--lr``.
- ``--ridge``: closed-form ridge regression from the last hidden layer's features (views 0..3,
  variant 0 of every training model) to per-shape template fits (the template fitted to each
  training target directly, as ``bench_fit_ceiling.py`` does), for a range of ridge weights;
  also the mean of those fits as a constant head (a sketch-blind readout).

If a re-fitted head beats the trained one by a wide margin, the features hold shape the training
has not read out yet; if not, the encoder's features are what limits the sketch reading.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
import torch
from bench_fit_ceiling import fit_to_targets  # this folder is on the path when run as a script

from train.data import DataSettings, make_loader
from train.fit import load_run, save_checkpoint, train_step, validation_chamfer
from train.model import TrainingNet
from train.objective import Objective


def per_shape_fits(objective: Objective, batches: list[dict], steps: int) -> dict[str, torch.Tensor]:
    """The template fitted to each training target (``bench_fit_ceiling.fit_to_targets``), by key."""
    fits = {}
    for batch in batches:
        params = fit_to_targets(objective, batch, steps)
        fits.update({k: params[i] for i, k in enumerate(batch["key"])})
    return fits


@torch.no_grad()
def hidden_features(model, batch: dict, view: int) -> torch.Tensor:
    """The last hidden layer's activation for one view of each item (B, F)."""
    z = model.latent(batch["images"][:, view : view + 1], batch["view_mask"][:, view : view + 1])
    for layer in model.hidden[1:]:
        z = layer(z)
    return z


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--checkpoint", required=True)
    ap.add_argument("--dataset", required=True)
    ap.add_argument("--category", required=True)
    ap.add_argument("--ridge", action="store_true")
    ap.add_argument("--fit-steps", type=int, default=150, help="Adam steps of each per-shape fit (--ridge)")
    ap.add_argument("--fits", default=None, help="cache file for the per-shape fits (--ridge)")
    ap.add_argument("--sgd-steps", type=int, default=0)
    ap.add_argument("--lr", type=float, default=1e-4)
    ap.add_argument("--out", default=None, help="save the run with the best re-fitted head here")
    a = ap.parse_args()
    torch.set_num_threads(int(os.environ.get("OMP_NUM_THREADS", "1")))
    run = load_run(a.checkpoint)
    model, tpl, s = run.model, run.template, run.settings
    objective = Objective(tpl, s.n_points, match_normals=s.match_normals)
    cpu = torch.device("cpu")
    val = list(
        make_loader(
            a.dataset,
            a.category,
            "val",
            DataSettings(eval_views=1, n_points=s.n_points, image_size=s.image_size),
            0,
            64,
            train=False,
        )
    )
    trained = (model.out.weight.detach().clone(), model.out.bias.detach().clone())
    best = (validation_chamfer(model, val, objective, cpu), trained)
    print(f"trained head: val L_Ch {best[0]:.4f}", flush=True)

    def set_head(weight, bias) -> float:
        with torch.no_grad():
            model.out.weight.copy_(torch.as_tensor(weight, dtype=torch.float32))
            model.out.bias.copy_(torch.as_tensor(bias, dtype=torch.float32))
        return validation_chamfer(model, val, objective, cpu)

    if a.ridge:
        t0 = time.process_time()
        train = list(
            make_loader(
                a.dataset,
                a.category,
                "train",
                DataSettings(eval_views=4, n_points=s.n_points, image_size=s.image_size),
                0,
                64,
                train=False,
            )
        )
        fits = (
            torch.load(a.fits, weights_only=True)
            if a.fits and os.path.exists(a.fits)
            else per_shape_fits(objective, train, a.fit_steps)
        )
        if a.fits:
            torch.save(fits, a.fits)
        rows, targets = [], []
        for batch in train:
            for view in range(batch["images"].shape[1]):
                h = hidden_features(model, batch, view)
                for i, key in enumerate(batch["key"]):
                    if batch["view_mask"][i, view]:
                        rows.append(h[i].numpy())
                        targets.append(fits[key].numpy())
        h, y = np.asarray(rows, np.float64), np.asarray(targets, np.float64)
        hm, ym = h.mean(0), y.mean(0)
        print(f"per-shape fits of {len(fits)} models, {len(h)} feature rows ({time.process_time() - t0:.0f} CPU s)")
        v = set_head(np.zeros(tuple(model.out.weight.shape)), ym)
        print(f"mean of the fits as a constant head: val L_Ch {v:.4f}")
        for alpha in (0.1, 1.0, 10.0, 100.0, 1000.0, 10000.0):
            w = np.linalg.solve((h - hm).T @ (h - hm) + alpha * np.eye(h.shape[1]), (h - hm).T @ (y - ym))
            head = (w.T, ym - hm @ w)
            v = set_head(*head)
            print(f"ridge {alpha:g}: val L_Ch {v:.4f}", flush=True)
            if v < best[0]:
                best = (v, head)
    if a.sgd_steps:
        set_head(*trained)
        for p in model.parameters():
            p.requires_grad_(False)
        for p in model.out.parameters():
            p.requires_grad_(True)
        opt = torch.optim.Adam(model.out.parameters(), lr=a.lr)
        data = DataSettings(max_views=s.max_views, n_points=s.n_points, image_size=s.image_size)
        stream = iter(make_loader(a.dataset, a.category, "train", data, 1, s.batch_size, 1, True))
        trainee = TrainingNet(model)
        for step in range(1, a.sgd_steps + 1):
            batch = next(stream)
            train_step(
                trainee, opt, objective, batch, objective.sample_st(torch.Generator().manual_seed(step)), s.weights, cpu
            )
            if step % 100 == 0:
                v = validation_chamfer(model, val, objective, cpu)  # the model stays in eval mode
                print(f"head-only step {step} (lr {a.lr:g}): val L_Ch {v:.4f}", flush=True)
                if v < best[0]:
                    best = (v, (model.out.weight.detach().clone(), model.out.bias.detach().clone()))
    print(f"best head: val L_Ch {best[0]:.4f}")
    if a.out:
        set_head(*best[1])
        save_checkpoint(a.out, model, torch.optim.Adam(model.parameters()), run.step, s, tpl, val_chamfer=best[0])


if __name__ == "__main__":
    main()
