"""``twin demo``: predict the thesis's horizontal endoscope across a few configurations.

Solves a κ × φ fan with and without a 10 g tip mass and saves a plot of the shapes: a quick
look at the predictor on its own, without a device.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from twin.cliargs import add_param_args, params_from_args
from twin.pose import HORIZONTAL
from twin.rod.grid import GRAVITY_TIP_FORCE_N, pcc_tensions_n


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="prediction demo: shapes of the horizontal endoscope under load")
    p.add_argument("--out", default="runs/demo", help="folder for the plot (default runs/demo)")
    add_param_args(p)
    p.set_defaults(func=run_demo)


def run_demo(args: argparse.Namespace) -> int:
    from twin.rod import RodModel, solve  # here: the parser is built without loading the kernels

    params = params_from_args(args)
    model = RodModel.from_params(params)
    g = params.environment.gravity_m_s2
    rows = []
    print(f"{'kappa 1/m':>9} {'phi deg':>8} {'mass g':>7} {'tip x mm':>9} {'tip y mm':>9} {'tip z mm':>9} {'ms':>6}")
    for kappa in (0.0, 13.0, 26.2):
        for phi in (0.0, 90.0, 180.0):
            for mass in (0.0, 0.010):
                sol = solve(model, pcc_tensions_n(kappa, phi, params), tip_force_n=GRAVITY_TIP_FORCE_N(mass, g),
                            base_rotation=HORIZONTAL)
                tip = sol.tip_position_m * 1e3
                print(f"{kappa:9.1f} {phi:8.0f} {mass * 1e3:7.0f} {tip[0]:9.2f} {tip[1]:9.2f} {tip[2]:9.2f} "
                      f"{sol.solve_time_s * 1e3:6.2f}")
                rows.append((kappa, phi, mass, sol))
    path = _plot(rows, Path(args.out))
    print(f"shapes plotted to {path}")
    return 0


def _plot(rows, out: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out.mkdir(parents=True, exist_ok=True)
    from matplotlib.lines import Line2D

    fig, axes = plt.subplots(1, 2, figsize=(10, 4.8), width_ratios=(3, 2))
    # One colour per commanded shape (κ, φ), solid without and dashed with the tip mass.
    shapes = sorted({(kappa, phi) for kappa, phi, _, _ in rows})
    colours = {shape: plt.cm.tab10(i % 10) for i, shape in enumerate(shapes)}
    for kappa, phi, mass, sol in rows:
        p = sol.positions_m * 1e3
        style = "-" if mass == 0 else "--"
        label = f"κ {kappa:g} 1/m, φ {phi:g}°" if mass == 0 else None
        axes[0].plot(p[:, 0], p[:, 2], style, lw=1.2, color=colours[kappa, phi], label=label)
        axes[1].plot(p[:, 1], p[:, 2], style, lw=1.2, color=colours[kappa, phi])
    masses = sorted({mass for _, _, mass, _ in rows})
    axes[0].set(xlabel="x (mm)", ylabel="z (mm)", title="side view")
    axes[1].set(xlabel="y (mm)", ylabel="z (mm)", title="front view")
    for ax in axes:
        ax.set_aspect("equal")
        ax.grid(alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()
    handles += [Line2D([], [], color="k", ls="-" if m == 0 else "--") for m in masses]
    labels += [f"tip mass {m * 1e3:g} g" for m in masses]
    fig.legend(handles, labels, loc="center right", fontsize=8, title="backbone (Cosserat)", title_fontsize=8)
    path = out / "shapes.png"
    fig.tight_layout(rect=(0, 0, 0.78, 1))
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
