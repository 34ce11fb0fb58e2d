"""``nlips calibrate-leds PRESS...``: LED parameters from captures of the undeformed dome -> LED JSON file."""

from __future__ import annotations


def register(subparsers) -> None:
    p = subparsers.add_parser("calibrate-leds", help="estimate LED Psi, mu, n_s, x_s from undeformed-dome captures")
    p.add_argument("presses", nargs="+", help="press folders of the undeformed dome (with reference.npz)")
    p.add_argument("--out", required=True, help="LED JSON file to write (use with `nlips solve --leds FILE`)")
    p.add_argument("--stride", type=int, default=2, help="use every N-th pixel (default 2)")
    p.add_argument("--loss", default="cauchy", choices=("cauchy", "soft_l1", "huber", "linear"))
    p.set_defaults(func=run)


def run(args) -> int:
    from ..config import check_count
    from ..core.capture import load_press
    from ..progress import track, working
    from ..solver import calibrate_leds, save_leds

    check_count("--stride", args.stride, minimum=1)
    presses = [load_press(f) for f in track(args.presses, desc="loading", unit="press")]
    with working(f"calibrating {len(presses[0].leds)} LEDs from {len(presses)} capture(s)"):
        cal = calibrate_leds(presses, stride=args.stride, loss=args.loss)
    save_leds(args.out, cal.leds, cal.to_json())
    head = ("LED", "Psi R", "Psi G", "Psi B", "mu", "+-mu", "+-dir(deg)", "+-pos(mm)")
    print(" ".join(f"{h:>{w}}" for h, w in zip(head, (3, 7, 7, 7, 6, 6, 10, 9))))
    for i, (led, sd) in enumerate(zip(cal.leds, cal.std)):
        r, g, b = led.intensity
        print(
            f"{i + 1:>3} {r:>7.3f} {g:>7.3f} {b:>7.3f} {led.mu:>6.3f} {sd['mu']:>6.3f} "
            f"{sd['direction_deg']:>10.3f} {max(sd['position_mm']):>9.4f}"
        )
    print(f"written {args.out} (gauge: mean Psi = 1 per channel; albedo {cal.albedo})")
    return 0
