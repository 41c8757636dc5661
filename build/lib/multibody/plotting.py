"""Figures of a simulated :class:`~multibody.simulation.Trajectory` (matplotlib, written as PNG files)."""

from __future__ import annotations

import os

import numpy as np


def pyplot():
    """matplotlib.pyplot with the file-only Agg backend."""
    import matplotlib

    matplotlib.use("Agg")  # files only; no screen needed
    import matplotlib.pyplot as plt

    return plt


def plot_trajectory(trajectory, out_dir, name, *, coordinate_labels=None, multiplier_labels=None):
    """Write four PNG figures of a trajectory and return their paths.

    ``<name>_state.png`` (q and v against t), ``<name>_energy.png`` (energy change relative to the
    start), ``<name>_residual.png`` (largest constraint violation, log scale) and
    ``<name>_multipliers.png`` (one curve per constraint row, when there are constraints).
    """
    plt = pyplot()
    os.makedirs(out_dir, exist_ok=True)
    t = trajectory.t
    paths = []

    def save(figure, suffix):
        path = os.path.join(out_dir, f"{name}_{suffix}.png")
        figure.tight_layout()
        figure.savefig(path, dpi=110)
        plt.close(figure)
        paths.append(path)

    figure, (ax_q, ax_v) = plt.subplots(2, 1, sharex=True, figsize=(7, 5))
    labels = coordinate_labels or [f"q{k}" for k in range(trajectory.q.shape[1])]
    for k in range(trajectory.q.shape[1]):
        ax_q.plot(t, trajectory.q[:, k], label=labels[k] if k < len(labels) else None)
    for k in range(trajectory.v.shape[1]):
        ax_v.plot(t, trajectory.v[:, k])
    ax_q.set_ylabel("q")
    ax_v.set_ylabel("v")
    ax_v.set_xlabel("t (s)")
    if trajectory.q.shape[1] <= 10:
        ax_q.legend(fontsize="small", ncol=2)
    save(figure, "state")

    figure, ax = plt.subplots(figsize=(7, 3))
    energy = trajectory.energy
    scale = max(np.abs(energy).max(), 1e-300)
    ax.plot(t, (energy - energy[0]) / scale)
    ax.set_ylabel("(E − E₀) / max|E|")
    ax.set_xlabel("t (s)")
    save(figure, "energy")

    figure, ax = plt.subplots(figsize=(7, 3))
    ax.semilogy(t, np.maximum(trajectory.residual, 1e-17))
    ax.set_ylabel("constraint residual")
    ax.set_xlabel("t (s)")
    save(figure, "residual")

    if trajectory.lam.shape[1]:
        figure, ax = plt.subplots(figsize=(7, 4))
        names = multiplier_labels or trajectory.row_names
        for k in range(trajectory.lam.shape[1]):
            ax.plot(t, trajectory.lam[:, k], label=names[k] if k < len(names) else None)
        ax.set_ylabel("λ")
        ax.set_xlabel("t (s)")
        ax.legend(fontsize="small")
        save(figure, "multipliers")
    return paths


def plot_path(xy, out_dir, name, title, labels=("x (m)", "y (m)")):
    """Write ``<name>_path.png``: a path ``xy (n, 2)`` seen from above, equal axes. Returns the file path."""
    plt = pyplot()
    os.makedirs(out_dir, exist_ok=True)
    figure, ax = plt.subplots(figsize=(6, 5))
    ax.plot(xy[:, 0], xy[:, 1])
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel(labels[0])
    ax.set_ylabel(labels[1])
    ax.set_title(title)
    figure.tight_layout()
    path = os.path.join(out_dir, f"{name}_path.png")
    figure.savefig(path, dpi=110)
    plt.close(figure)
    return path
