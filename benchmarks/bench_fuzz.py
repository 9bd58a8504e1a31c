"""Fuzzing benchmark: tens of thousands of mutated BVH files through the
reader, forward kinematics and retargeting.

Each mutation starts from a seed clip (the packaged walk/squat/arm_raise and
the data set's BVH files cut to their first 30 frames) and applies 1-3
random edits: a number replaced by an extreme one (1e308, 5e-324, nan, -0,
huge integers...), a token deleted, duplicated or replaced by a keyword or
brace, a line deleted, duplicated or swapped, the file truncated, the
``Frames``/``Frame Time`` values changed, a 300-2,000 deep joint chain
inserted, random bytes. The file is then read (:func:`read_bvh`), its joints
posed over every frame, and retargeted onto a 2-joint skeleton at 30 fps.

Outcome of each mutation: ``ok`` (every joint transform finite), or the
project error it raised (by class). Anything else is counted as a failure:
``crash:<exception>`` (another exception type), ``no_location`` (a project
error whose message does not start with the file's path), or
``non_finite`` (accepted, but NaN/inf came out). The run passes when those
counts are all zero.

Run alone: ``python3 benchmarks/bench_fuzz.py [--full] [--count N]`` (default
50,000 mutations; the seed is fixed).
"""
from __future__ import annotations

import collections
import json
import random
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks import BVH_DIR, DEFAULT_OUT, REPO, format_table  # noqa: E402

COUNT = 50_000
SEED = 21
EXTREME = ["1e308", "-1e308", "1e200", "5e-324", "-5e-324", "nan", "inf", "-inf", "0", "-0", "1e-300",
           "99999999999999999999", "-1", "3.4e38", "1e16", "0x10", "1,5", "", "1e", "++1", "86400",
           "0.0000001", "1e6", "360000000"]
WORDS = ["{", "}", "JOINT", "ROOT", "End", "Site", "OFFSET", "CHANNELS", "MOTION", "HIERARCHY",
         "Frames:", "Frame", "Time:", "Xrotation", "Yposition", "Wrotation", "3", "6", "-3", "9",
         "Hips", "\ufeff", "\t", "é"]


def seed_clips() -> dict[str, str]:
    """Seed BVH texts: the packaged clips and the data set's, cut to 30 frames."""
    paths = sorted((REPO / "wearfit_usd" / "motions").glob("*.bvh"))
    if BVH_DIR.exists():
        paths += sorted(BVH_DIR.glob("*.bvh"))
    out = {}
    for p in paths:
        lines = p.read_text(encoding="utf-8", errors="replace").splitlines()
        m = next(i for i, ln in enumerate(lines) if ln.strip() == "MOTION")
        n = min(30, len(lines) - m - 3)
        lines = lines[:m + 1] + [f"Frames: {n}"] + lines[m + 2:m + 3 + n]
        out[p.name] = "\n".join(lines) + "\n"
    return out


def _deep_chain(depth: int) -> list[str]:
    lines = []
    for i in range(depth):
        lines += [f"JOINT fz{i}", "{", "OFFSET 0 0.5 0"]
    lines += ["End Site", "{", "OFFSET 0 0.5 0", "}"] + ["}"] * depth
    return lines


def mutate(text: str, rng: random.Random) -> str:
    """1-3 random edits of a BVH text (see the module docstring)."""
    lines = text.splitlines()
    for _ in range(rng.randint(1, 3)):
        op = rng.random()
        i = rng.randrange(len(lines)) if lines else 0
        toks = lines[i].split() if lines else []
        if op < 0.35 and toks:          # a number -> an extreme value
            nums = [k for k, t in enumerate(toks) if t.lstrip("-").replace(".", "", 1).isdigit()]
            k = rng.choice(nums) if nums else rng.randrange(len(toks))
            toks[k] = rng.choice(EXTREME)
            lines[i] = " ".join(toks)
        elif op < 0.50 and toks:        # a token deleted, duplicated or replaced
            k = rng.randrange(len(toks))
            what = rng.random()
            if what < 0.33:
                del toks[k]
            elif what < 0.66:
                toks.insert(k, toks[k])
            else:
                toks[k] = rng.choice(WORDS)
            lines[i] = " ".join(toks)
        elif op < 0.62 and lines:       # a line deleted, duplicated or swapped
            what = rng.random()
            if what < 0.4:
                del lines[i]
            elif what < 0.7:
                lines.insert(i, lines[i])
            else:
                j = rng.randrange(len(lines))
                lines[i], lines[j] = lines[j], lines[i]
        elif op < 0.70:                 # truncated
            cut = rng.randrange(len(text) + 1)
            lines = "\n".join(lines)[:cut].splitlines()
        elif op < 0.82:                 # the MOTION header
            k = next((n for n, ln in enumerate(lines) if ln.startswith("Frame")), None)
            if k is not None:
                key = rng.choice(["Frames:", "Frame Time:"])
                k2 = next((n for n, ln in enumerate(lines) if ln.startswith(key)), k)
                lines[k2] = f"{key} {rng.choice(EXTREME)}"
        elif op < 0.86:                 # a deep chain below the first joint
            k = next((n for n, ln in enumerate(lines) if "CHANNELS" in ln), None)
            if k is not None:
                lines[k + 1:k + 1] = _deep_chain(rng.choice([300, 1000, 2000]))
        elif op < 0.93 and lines:       # random bytes in a line
            s = lines[i]
            pos = rng.randrange(len(s) + 1)
            junk = "".join(chr(rng.choice([0, 7, 9, 13, 0xFEFF, 0xFFFD, rng.randrange(32, 127)]))
                           for _ in range(rng.randint(1, 6)))
            lines[i] = s[:pos] + junk + s[pos:]
        else:                           # a CHANNELS count changed
            k = [n for n, ln in enumerate(lines) if "CHANNELS" in ln]
            if k:
                n = rng.choice(k)
                t = lines[n].split()
                if len(t) > 1:
                    t[1] = rng.choice(["0", "1", "2", "7", "-6", "x", "1e3"])
                    lines[n] = " ".join(t)
    return "\n".join(lines) + "\n"


def target_skeleton():
    """The 2-joint skeleton of tests/tiny_stage.py (hips, spine)."""
    sys.path.insert(0, str(REPO))
    from tests.tiny_stage import write_tiny
    from wearfit_usd.io.usd import read_character
    with tempfile.TemporaryDirectory() as tmp:
        return read_character(write_tiny(Path(tmp) / "tiny.usda")).skeleton


def check_one(path: Path, skeleton) -> str:
    """Read, pose and retarget one BVH file; the outcome (see the module docstring)."""
    from wearfit_usd.errors import WearfitError
    from wearfit_usd.io.bvh import read_bvh
    from wearfit_usd.motion.retarget import retarget
    try:
        m = read_bvh(path)
        if m.n_frames == 0:
            return "ok_empty"
        g = m.global_transforms()
        if not np.isfinite(g).all():
            return "non_finite"
        rt = retarget(m, skeleton, fps=30.0, max_frames=20_000)
        if not (np.isfinite(rt.world).all() and np.isfinite(rt.local).all()):
            return "non_finite"
        return "ok"
    except WearfitError as exc:
        if not str(exc).startswith(str(path)):
            return f"no_location:{type(exc).__name__}"
        return type(exc).__name__
    except Exception as exc:  # noqa: BLE001 - every other exception is the finding
        return f"crash:{type(exc).__name__}"


def fuzz(count: int = COUNT, seed: int = SEED, out_dir: Path | None = None):
    """Run ``count`` mutations; returns (outcome counts, examples, seconds)."""
    rng = random.Random(seed)
    seeds = seed_clips()
    names = sorted(seeds)
    skeleton = target_skeleton()
    counts: collections.Counter = collections.Counter()
    examples: dict[str, str] = {}
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        path = Path(tmp) / "fuzz.bvh"
        for n in range(count):
            text = mutate(seeds[names[n % len(names)]], rng)
            path.write_text(text, encoding="utf-8", errors="surrogatepass")
            outcome = check_one(path, skeleton)
            counts[outcome] += 1
            bad = outcome.startswith(("crash", "no_location", "non_finite"))
            if bad and outcome not in examples and out_dir is not None:
                keep = Path(out_dir) / f"fuzz_{outcome.replace(':', '_')}.bvh"
                keep.write_text(text, encoding="utf-8", errors="surrogatepass")
                examples[outcome] = str(keep)
    return counts, examples, time.perf_counter() - t0


def run(full: bool, out_dir: Path) -> list[dict]:
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    count = COUNT * (2 if full else 1)
    counts, examples, secs = fuzz(count, SEED, out_dir)
    failures = sum(v for k, v in counts.items() if k.startswith(("crash", "no_location", "non_finite")))
    rows = [{"outcome": k, "mutations": v, "share_pct": round(100.0 * v / count, 2),
             "failure": k.startswith(("crash", "no_location", "non_finite"))}
            for k, v in sorted(counts.items(), key=lambda kv: -kv[1])]
    rows.append({"outcome": "TOTAL", "mutations": count, "share_pct": 100.0, "failure": failures > 0,
                 "seconds": round(secs, 1), "mutations_per_s": round(count / secs, 1)})
    (out_dir / "fuzz.json").write_text(json.dumps({"seed": SEED, "count": count, "counts": dict(counts),
                                                   "failures": failures, "examples": examples,
                                                   "seconds": secs}, indent=2))
    return rows


def main(argv=None) -> int:
    import argparse
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--full", action="store_true", help="twice the mutations")
    ap.add_argument("--count", type=int, default=None, help=f"mutations (default {COUNT})")
    ap.add_argument("--out", default=str(DEFAULT_OUT))
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.count:
        counts, examples, secs = fuzz(args.count, SEED, out)
        rows = [{"outcome": k, "mutations": v} for k, v in counts.most_common()]
        rows.append({"outcome": "TOTAL", "mutations": args.count, "seconds": round(secs, 1)})
    else:
        rows = run(args.full, out)
    print(format_table(rows))
    bad = [r for r in rows if r.get("failure") or str(r["outcome"]).startswith(("crash", "no_loc", "non_f"))]
    bad = [r for r in bad if r["outcome"] != "TOTAL"]
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
