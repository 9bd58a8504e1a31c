"""Job files: references x targets x clips and the products wanted.

A job file (JSON, YAML or CSV) names references (reference bodies wearing
their items), targets (bodies) and clips (BVH with an optional frame range),
and the products: ``fit`` (fitted body USD), ``dress`` (dressed USD),
``animate`` (one shot per clip) and ``preview`` (a rendered image of the
dressed target). JSON/YAML::

    {"references": ["ref_a.usda", {"path": "ref_b.usda", "targets": ["b1.usdc"]}],
     "targets": ["body_b.usdc", ...],
     "clips": [{"path": "walk.bvh", "start": 1, "end": 61}, "run.bvh"],
     "products": ["dress", "animate"],
     "options": {"k": 5, "format": "usd"}}

expands to the cross product (a reference given as a mapping with its own
``targets`` is crossed with those instead), or lists explicit rows under
``"jobs"``: ``[{"reference": ..., "target": ..., "clips": [...], "products": [...]}]``.
A CSV file holds explicit rows with the columns ``reference,target`` and
optionally ``clip,start,end,products`` (products separated by ``;`` or spaces).
A clip's ``start`` is a frame number or ``"auto"`` (the default, as ``wearfit
animate --start auto``: frame 1 when frame 0 is a converter's rest pose, see
:mod:`motion.clip_start`, decided when the clip is read).
Relative paths resolve against the job file's folder. Files are not opened
here: a missing input fails its own jobs when the batch runs.
"""
from __future__ import annotations

import csv
import json
import re
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import InputError

PRODUCTS = ("fit", "dress", "animate", "preview")
FORMATS = ("usd", "usda", "usdc")
DEFAULT_OPTIONS = {"k": 5, "format": "usd", "fps": 30.0, "preview_size": [320, 400]}


@dataclass(frozen=True)
class Clip:
    """A BVH clip and its frame range (``end`` exclusive, None = to the end)."""
    path: Path
    start: int | None = None  # None: "auto" (motion.clip_start.leading_rest_frames when the clip is read)
    end: int | None = None

    @property
    def label(self) -> str:
        first = "auto" if self.start is None else self.start
        rng = f"{first}-{self.end}" if self.end is not None else f"{first}-"
        return f"{self.path.stem}_{rng}"


@dataclass(frozen=True)
class Job:
    """One product of one reference on one target (and one clip for ``animate``)."""
    product: str
    reference: Path
    target: Path
    clip: Clip | None = None

    @property
    def name(self) -> str:
        parts = [self.reference.stem, self.target.stem] + ([self.clip.label] if self.clip else [])
        return "__".join(parts)

    @property
    def id(self) -> str:
        return f"{self.product}/{self.name}"


@dataclass
class JobSet:
    """The expanded job file: every job once, in file order, and the options."""
    source: Path
    jobs: list[Job]
    options: dict = field(default_factory=lambda: dict(DEFAULT_OPTIONS))

    def inputs(self) -> list[Path]:
        """Every input file the jobs read, once each."""
        seen: dict[Path, None] = {}
        for j in self.jobs:
            seen.setdefault(j.reference)
            seen.setdefault(j.target)
            if j.clip is not None:
                seen.setdefault(j.clip.path)
        return list(seen)


def _fail(src: Path, message: str):
    raise InputError(src, message)


def _path(src: Path, value, what: str) -> Path:
    if not isinstance(value, str) or not value.strip():
        _fail(src, f"{what} must be a file path (a non-empty string), got {value!r}")
    p = Path(value.strip()).expanduser()
    return p if p.is_absolute() else (src.parent / p).resolve()


def _int(src: Path, value, what: str, also: str = "") -> int | None:
    if value is None or value == "":
        return None
    if isinstance(value, bool) or not isinstance(value, (int, str)) or not re.fullmatch(r"-?\d+", str(value).strip()):
        _fail(src, f"{what} must be an integer frame number{also}, got {value!r}")
    return int(str(value).strip())


def _clip(src: Path, value, where: str) -> Clip:
    if isinstance(value, str):
        return Clip(_path(src, value, f"{where}"))
    if not isinstance(value, dict):
        _fail(src, f"{where} must be a path or a mapping with 'path', 'start', 'end', got {value!r}")
    unknown = set(value) - {"path", "start", "end"}
    if unknown:
        _fail(src, f"{where}: unknown keys {sorted(unknown)} (known: path, start, end)")
    if "path" not in value:
        _fail(src, f"{where}: a clip needs a 'path'")
    raw = value.get("start")
    start = None if isinstance(raw, str) and raw.strip().lower() == "auto" else _int(src, raw, f"{where}.start",
                                                                                      also=" or auto")
    end = _int(src, value.get("end"), f"{where}.end")
    if (start is not None and start < 0) or (end is not None and end <= (start or 0)):
        _fail(src, f"{where}: the frame range {start}..{end} is empty or negative")
    return Clip(_path(src, value["path"], f"{where}.path"), start, end)


def _products(src: Path, value, where: str) -> list[str]:
    if isinstance(value, str):
        value = [s for s in re.split(r"[;,\s]+", value) if s]
    if not isinstance(value, list) or not value:
        _fail(src, f"{where} must be a non-empty list of products ({', '.join(PRODUCTS)})")
    bad = [p for p in value if p not in PRODUCTS]
    if bad:
        _fail(src, f"{where}: unknown products {bad} (known: {', '.join(PRODUCTS)})")
    return list(dict.fromkeys(value))


def _list(src: Path, data: dict, key: str, required: bool) -> list:
    value = data.get(key)
    if value is None:
        if required:
            _fail(src, f"'{key}' is missing: list at least one")
        return []
    if not isinstance(value, list) or (required and not value):
        _fail(src, f"'{key}' must be a non-empty list")
    return value


def _expand(src: Path, products: list[str], reference: Path, target: Path, clips: list[Clip],
            where: str) -> list[Job]:
    jobs = []
    for p in products:
        if p == "animate":
            if not clips:
                _fail(src, f"{where}: 'animate' needs at least one clip")
            jobs += [Job(p, reference, target, c) for c in clips]
        else:
            jobs.append(Job(p, reference, target))
    return jobs


def _options(src: Path, value) -> dict:
    opts = dict(DEFAULT_OPTIONS)
    if value is None:
        return opts
    if not isinstance(value, dict):
        _fail(src, f"'options' must be a mapping, got {value!r}")
    unknown = set(value) - set(DEFAULT_OPTIONS)
    if unknown:
        _fail(src, f"options: unknown keys {sorted(unknown)} (known: {', '.join(DEFAULT_OPTIONS)})")
    opts.update(value)
    if isinstance(opts["k"], bool) or not isinstance(opts["k"], int) or opts["k"] < 1:
        _fail(src, f"options.k must be an integer >= 1, got {opts['k']!r}")
    if opts["format"] not in FORMATS:
        _fail(src, f"options.format must be one of {', '.join(FORMATS)}, got {opts['format']!r}")
    if not isinstance(opts["fps"], (int, float)) or isinstance(opts["fps"], bool) or opts["fps"] <= 0:
        _fail(src, f"options.fps must be a positive number, got {opts['fps']!r}")
    size = opts["preview_size"]
    if (not isinstance(size, list) or len(size) != 2
            or not all(isinstance(s, int) and not isinstance(s, bool) and s > 0 for s in size)):
        _fail(src, f"options.preview_size must be [width, height] in pixels, got {size!r}")
    return opts


def from_mapping(src: Path, data) -> JobSet:
    """Expand the parsed content of a JSON/YAML job file ``src``."""
    if not isinstance(data, dict):
        _fail(src, "a job file holds a mapping with 'references', 'targets', 'clips', 'products' (or 'jobs')")
    known = {"references", "targets", "clips", "products", "jobs", "options"}
    unknown = set(data) - known
    if unknown:
        _fail(src, f"unknown keys {sorted(unknown)} (known: {', '.join(sorted(known))})")
    options = _options(src, data.get("options"))
    clips = [_clip(src, c, f"clips[{i}]") for i, c in enumerate(_list(src, data, "clips", False))]
    products = _products(src, data.get("products", ["dress"]), "products")
    jobs: list[Job] = []
    if "jobs" in data:
        if "references" in data or "targets" in data:
            _fail(src, "give either 'jobs' (explicit rows) or 'references' and 'targets' (cross product), not both")
        for i, row in enumerate(_list(src, data, "jobs", True)):
            where = f"jobs[{i}]"
            if not isinstance(row, dict):
                _fail(src, f"{where} must be a mapping with 'reference' and 'target'")
            bad = set(row) - {"reference", "target", "clips", "clip", "products"}
            if bad:
                _fail(src, f"{where}: unknown keys {sorted(bad)}")
            for key in ("reference", "target"):
                if key not in row:
                    _fail(src, f"{where}: '{key}' is missing")
            row_clips = clips
            if "clip" in row:
                row_clips = [_clip(src, row["clip"], f"{where}.clip")]
            elif "clips" in row:
                row_clips = [_clip(src, c, f"{where}.clips[{k}]") for k, c in enumerate(row["clips"])]
            row_products = _products(src, row["products"], f"{where}.products") if "products" in row else products
            jobs += _expand(src, row_products, _path(src, row["reference"], f"{where}.reference"),
                            _path(src, row["target"], f"{where}.target"), row_clips, where)
    else:
        targets = [_path(src, t, f"targets[{i}]") for i, t in enumerate(_list(src, data, "targets", False))]
        for i, ref in enumerate(_list(src, data, "references", True)):
            where = f"references[{i}]"
            ref_targets = targets
            if isinstance(ref, dict):
                bad = set(ref) - {"path", "targets"}
                if bad:
                    _fail(src, f"{where}: unknown keys {sorted(bad)} (known: path, targets)")
                if "targets" in ref:
                    if not isinstance(ref["targets"], list) or not ref["targets"]:
                        _fail(src, f"{where}.targets must be a non-empty list")
                    ref_targets = [_path(src, t, f"{where}.targets[{k}]") for k, t in enumerate(ref["targets"])]
                ref = ref.get("path")
            ref_path = _path(src, ref, where)
            if not ref_targets:
                _fail(src, f"{where}: no targets ('targets' is missing or empty)")
            for tgt in ref_targets:
                jobs += _expand(src, products, ref_path, tgt, clips, where)
    return JobSet(src, list(dict.fromkeys(jobs)), options)


def from_csv(src: Path, text: str) -> JobSet:
    """Expand a CSV job file: one row per reference/target (and clip)."""
    rows = list(csv.DictReader(text.splitlines()))
    if not rows:
        _fail(src, "no rows: a CSV job file needs a header 'reference,target[,clip,start,end,products]' and rows")
    header = set(rows[0])
    missing = {"reference", "target"} - header
    if missing:
        _fail(src, f"the CSV header lacks the columns {sorted(missing)}")
    unknown = header - {"reference", "target", "clip", "start", "end", "products"}
    if unknown:
        _fail(src, f"unknown CSV columns {sorted(unknown)}")
    jobs: list[Job] = []
    for n, row in enumerate(rows, start=2):
        where = f"line {n}"
        clips = []
        if (row.get("clip") or "").strip():
            clips = [_clip(src, {"path": row["clip"], "start": row.get("start"), "end": row.get("end")}, where)]
        products = _products(src, row.get("products") or ("dress animate" if clips else "dress"), f"{where}: products")
        jobs += _expand(src, products, _path(src, row.get("reference"), f"{where}: reference"),
                        _path(src, row.get("target"), f"{where}: target"), clips, where)
    return JobSet(src, list(dict.fromkeys(jobs)), dict(DEFAULT_OPTIONS))


def load_jobs(path) -> JobSet:
    """Read and expand a job file (``.json``, ``.yaml``/``.yml`` or ``.csv``).

    Parameters
    ----------
    path : str or Path
        The job file; relative paths inside it resolve against its folder.

    Returns
    -------
    JobSet
        Every job (one product of one reference/target/clip) once, in file order.

    Raises
    ------
    InputError
        Naming the file and the problem (unreadable, bad syntax, unknown keys,
        unknown products, bad frame ranges...).
    """
    src = Path(path).resolve()
    if not src.is_file():
        _fail(src, "job file not found")
    try:
        text = src.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        _fail(src, f"cannot read the job file: {exc}")
    suffix = src.suffix.lower()
    if suffix == ".json":
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise InputError(src, f"invalid JSON: {exc.msg} (column {exc.colno})", line=exc.lineno) from None
        return from_mapping(src, data)
    if suffix in (".yaml", ".yml"):
        import yaml  # PyYAML: only YAML job files need it
        try:
            data = yaml.safe_load(text)
        except yaml.YAMLError as exc:
            mark = getattr(exc, "problem_mark", None)
            raise InputError(src, f"invalid YAML: {getattr(exc, 'problem', None) or exc}",
                             line=mark.line + 1 if mark is not None else None) from None
        return from_mapping(src, data)
    if suffix == ".csv":
        return from_csv(src, text)
    _fail(src, "a job file ends in .json, .yaml, .yml or .csv")
