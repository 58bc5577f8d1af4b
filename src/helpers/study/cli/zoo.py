"""The zoo's command line: ``python -m helpers.study.cli.zoo``
``train NAME [NAME ...] [--publish] [--until HH:MM | --minutes N]`` | ``snapshot NAME`` | ``list`` | ``verify`` | ``speeds``."""

from __future__ import annotations

from dataclasses import replace

from ..zoo import RECIPES, progress, publish, recipe, refresh_speeds, snapshot, train_recipe, verify
from .train_until import deadline_from, train_until


def main(argv: list[str] | None = None) -> int:
    """``python -m helpers.study.cli.zoo train NAME [NAME ...] [--publish] [--until HH:MM | --minutes N]`` |
    ``snapshot NAME`` | ``list`` | ``verify``
    | ``speeds``."""
    import argparse

    ap = argparse.ArgumentParser(prog="python -m helpers.study.cli.zoo", description=main.__doc__)
    sub = ap.add_subparsers(dest="cmd", required=True)
    t = sub.add_parser("train", help="train (or resume) zoo recipes; --publish writes models/<name>.*")
    t.add_argument("names", nargs="+")
    t.add_argument("--publish", action="store_true")
    t.add_argument("--device", default="auto")
    t.add_argument("--recipes", default=str(RECIPES), help="recipe file (default: the long preset's zoo.yaml)")
    t.add_argument("--workers", type=int, default=0, help="rendering processes (default: the recipe's)")
    t.add_argument("--until", default="", help="stop at the last epoch boundary before this local time (HH:MM) "
                   "and copy the checkpoint to models/checkpoints/ (resume later with zoo train NAME); exit "
                   "status 3 when a training was stopped before its end")
    t.add_argument("--minutes", type=float, default=0.0, help="as --until, this many minutes from now")
    s = sub.add_parser("snapshot", help="commit-ready copy of an unfinished run's last.pt")
    s.add_argument("names", nargs="+")
    s.add_argument("--recipes", default=str(RECIPES), help="recipe file (default: the long preset's zoo.yaml)")
    sub.add_parser("list", help="every recipe: published (with its validation), committed checkpoint or untrained")
    sub.add_parser("verify", help="check every committed model file against its sha256")
    sub.add_parser("speeds", help="rewrite each entry's images/s from its history (median over quiet epochs)")
    a = ap.parse_args(argv)
    if a.cmd == "train":
        try:
            deadline = deadline_from(a.until, a.minutes) if a.until or a.minutes else None
        except ValueError as e:
            ap.error(str(e))
        for name in a.names:
            r = recipe(name, path=a.recipes, device=a.device)
            if a.workers:  # rendering processes do not change the pixels (not part of any cache key)
                r = replace(r, data=replace(r.data, workers=a.workers))
            if deadline is not None and train_until(r, deadline, a.recipes, a.device, a.workers) != "finished":
                return 3  # stopped before its end (its checkpoint kept): the later names wait for the next session
            model, run, info, data = train_recipe(r)  # with a deadline: loads the run the child finished
            print(f"{name}: trained in {run}")
            if a.publish:
                print(f"{name}: published {publish(r, run, data)}")
    elif a.cmd == "snapshot":
        for name in a.names:
            print(snapshot(recipe(name, path=a.recipes)))
    elif a.cmd == "list":
        rows = progress()
        for row in rows:
            val = "" if not row["val"] else (f"; seen-object validation Rota. Acc. {100 * row['val']['rot_acc']:.1f} %, "
                                             f"Class. Acc. {100 * row['val']['class_acc']:.1f} %")
            took = "" if not row["train_seconds"] else (f"; {row['train_seconds'] / 60:.0f} min ({row['precision']}, "
                                                        f"{row['images_per_s']:.0f} images/s)")
            print(f"{row['name']:14s} {row['state']:10s} {row['steps']:5d} / {row['budget'] or '?'} steps{val}{took}")
        done = [r for r in rows if r["state"] == "published"]
        print(f"published {len(done)} of {len(rows)} recipes, "
              f"{sum(r['train_seconds'] or 0 for r in done) / 3600:.1f} h of training in all")
    elif a.cmd == "speeds":
        for name, v in refresh_speeds().items():
            print(f"{name:14s} {v:.1f} images/s")
    elif a.cmd == "verify":
        bad = verify()
        for b in bad:
            print(b)
        return 1 if bad else 0
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
