"""What one batch item is, and the items a folder, a glob or a manifest names.

An item is one run of a single-item command: its kind (``observe``, ``tune``, ``analyze``,
``simulate``), the model, its input (a bag, or a torque table for simulate; a study point
has none), the command's options as on its command line, and the manifest's descriptive
columns (robot, date, label) that go to the results table. Its ``key`` changes whenever
anything that decides its result changes (the inputs' sizes and modification times
included), so a complete item folder with the same key is the same result.
"""

from __future__ import annotations

import csv
import glob
import hashlib
import io
import json
import os
import re
import shlex
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from elastic_pm_dyn.errors import InputError
from elastic_pm_dyn.text_file import TextFileError, read_head, read_text

KINDS = ("observe", "tune", "analyze", "simulate")
INPUT_COLUMN = {"observe": "bag", "tune": "bag", "analyze": "bag", "simulate": "torques"}
META_COLUMNS = ("robot", "date", "label")  # carried to the table, not given to the command
MANIFEST_SUFFIXES = (".csv", ".yaml", ".yml")
BAG_SUFFIXES = (".mcap", ".db3")
TRUE, FALSE = ("true", "yes", "on"), ("false", "no", "off", "")
MAX_MANIFEST_BYTES = 4 * 2**20  # a CSV manifest: some 40 000 rows of bag paths
FORMAT = 1  # bump when a runner's outputs change: every item is redone


@dataclass(frozen=True)
class Item:
    """One run; see the module docstring. ``options``: (name, value text) pairs, names as the
    command's long options without dashes (``max_evaluations`` or ``max-evaluations``)."""

    kind: str
    id: str
    model: str
    source: str = ""
    options: tuple[tuple[str, str], ...] = ()
    meta: tuple[tuple[str, str], ...] = ()
    study: tuple[tuple[str, object], ...] = ()  # a study point: parameter -> value

    @property
    def key(self) -> str:
        """Hash of everything that decides the result (see the module docstring)."""
        spec = {"format": FORMAT, "kind": self.kind, "model": self.model, "source": self.source,
                "options": list(self.options), "study": [[k, repr(v)] for k, v in self.study],
                "files": [_stamp(p) for p in (self.model, self.source) if p]}
        return hashlib.sha256(json.dumps(spec, sort_keys=True).encode()).hexdigest()[:20]

    def argv_options(self) -> list[str]:
        """The options as command-line words: ``--name value...`` (a value is split like a shell
        does; ``set`` takes ``;``-separated NAME=VALUE entries, each its own ``--set``; true/false
        for a flag)."""
        words: list[str] = []
        for name, value in self.options:
            flag = "--" + name.replace("_", "-")
            text = str(value).strip()
            if name == "set":
                words += [w for part in text.split(";") if part.strip() for w in (flag, part.strip())]
            elif text.lower() in TRUE:
                words.append(flag)
            elif text.lower() in FALSE:
                continue
            else:
                words += [flag, *shlex.split(text)]
        return words

    def row(self) -> dict[str, object]:
        """The item's own columns of the results table."""
        return {"id": self.id, "kind": self.kind, **dict(self.meta), "model": self.model, "source": self.source,
                **{f"option.{k}": v for k, v in self.options}, **{f"param.{k}": v for k, v in self.study}}


def _stamp(path: str) -> list:
    """Size and modification time of a file, or of every file in a folder (a bag)."""
    p = Path(path)
    try:
        files = sorted(f for f in p.rglob("*") if f.is_file()) if p.is_dir() else [p]
        return [[str(f.relative_to(p)) if p.is_dir() else "", f.stat().st_size, f.stat().st_mtime_ns] for f in files]
    except OSError:
        return ["missing"]


def is_bag(path: Path) -> bool:
    """A rosbag2 folder (metadata.yaml, or storage files and no sub-folders) or a bare .mcap/.db3 file."""
    if path.is_file():
        return path.suffix in BAG_SUFFIXES
    if not path.is_dir():
        return False
    if (path / "metadata.yaml").is_file():
        return True
    children = [c for c in path.iterdir() if not c.name.startswith(".")]
    # storage files beside folders are strays of a fleet folder (each its own item), not one bag
    return any(f.suffix in BAG_SUFFIXES and f.is_file() for f in children) and not any(c.is_dir() for c in children)


def _sources_in(path: Path, kind: str) -> list[Path]:
    """The bags (or torque tables) in ``path``, itself included, at any depth (not inside a bag)."""
    if kind != "simulate":
        if is_bag(path):
            return [path]
        if not path.is_dir():
            return []
        found: list[Path] = []
        for child in sorted(path.iterdir()):
            if not child.name.startswith("."):
                found += _sources_in(child, kind)
        return found
    if path.is_file():
        return [path] if path.suffix == ".csv" else []
    return sorted(p for p in path.rglob("*.csv") if not any(s.startswith(".") for s in p.relative_to(path).parts))


def slug(text: str) -> str:
    """A folder name from any text: letters, digits, ``._-``."""
    s = re.sub(r"[^A-Za-z0-9._-]+", "-", text).strip("-.")
    return s[:120] or "item"


def _ids(paths: Sequence[Path]) -> list[str]:
    """Short unique names: each path relative to the paths' common folder, suffix dropped."""
    if not paths:
        return []
    absolute = [p.resolve() for p in paths]
    root = Path(os.path.commonpath([str(p.parent) for p in absolute]))
    names = [slug(str(p.relative_to(root).with_suffix("")).replace(os.sep, "-")) for p in absolute]
    return unique(names)


def unique(names: Iterable[str]) -> list[str]:
    seen: dict[str, int] = {}
    out = []
    for n in names:
        seen[n] = seen.get(n, 0) + 1
        out.append(n if seen[n] == 1 else f"{n}-{seen[n]}")
    return out


def _is_manifest(path: Path, kind: str) -> bool:
    if not path.is_file() or path.suffix not in MANIFEST_SUFFIXES:
        return False
    if path.suffix != ".csv":
        return True
    try:
        head = read_head(path, 65536).decode("utf-8", errors="replace")  # the header row
    except TextFileError:
        return False
    header = next(csv.reader(io.StringIO(head, newline="")), [])
    return INPUT_COLUMN[kind] in [h.strip() for h in header] or "id" in [h.strip() for h in header]


@dataclass
class Inputs:
    """What the command line or the API gives for every item; a manifest row overrides it."""

    kind: str
    model: str | None = None
    options: Mapping[str, object] = field(default_factory=dict)


def discover(inputs: Sequence[str | Path], common: Inputs) -> list[Item]:
    """Items of folders, globs, single bags/tables and manifests (CSV/YAML), in the given order."""
    if common.kind not in KINDS:
        raise InputError(f"unknown batch kind {common.kind!r} (expected one of {', '.join(KINDS)})")
    items: list[Item] = []
    plain: list[Path] = []
    for text in inputs:
        path = Path(text)
        if glob.has_magic(str(text)):
            matches = [Path(m) for m in sorted(glob.glob(str(text), recursive=True))]
            if not matches:
                raise InputError(f"{text}: no file or folder matches")
            for m in matches:
                plain += _sources_in(m, common.kind)
        elif not path.exists():
            raise InputError(f"{text}: no such file or folder")
        elif _is_manifest(path, common.kind):
            items += read_manifest(path, common)
        else:
            found = _sources_in(path, common.kind)
            if not found:
                what = "torque table (.csv)" if common.kind == "simulate" else "bag"
                raise InputError(f"{text}: no {what} in it")
            plain += found
    if plain:
        model = _model(common.model, "the command line (--model)")
        options = _option_pairs(common.options)
        items += [Item(common.kind, i, model, str(p.resolve()), options) for i, p in zip(_ids(plain), plain,
                                                                                            strict=True)]
    return check_unique(items)


def check_unique(items: list[Item]) -> list[Item]:
    seen: dict[str, str] = {}
    for it in items:
        if it.id in seen:
            raise InputError(f"two items named {it.id!r} ({seen[it.id]} and {it.source or it.id}): give the "
                             "manifest an 'id' column")
        seen[it.id] = it.source or it.id
    return items


def _model(model: str | Path | None, where: str) -> str:
    if model is None:
        raise InputError(f"no model for the items of {where}: give --model (or a 'model' column)")
    path = Path(model)
    if not path.is_file():
        raise InputError(f"model {model}: no such file")
    return str(path.resolve())


def _option_pairs(options: Mapping[str, object]) -> tuple[tuple[str, str], ...]:
    pairs = []
    for name, value in options.items():
        if isinstance(value, bool):
            value = "true" if value else "false"
        elif isinstance(value, list | tuple):
            value = (";" if name == "set" else " ").join(str(v) for v in value)
        pairs.append((str(name).replace("-", "_"), str(value)))
    return tuple(sorted(pairs))


def read_manifest(path: Path, common: Inputs) -> list[Item]:
    """One item per row: ``id`` (optional), ``model`` (else --model), the bag or torque table
    (relative to the manifest's folder), robot/date/label, and any command option."""
    rows = _manifest_rows(path)
    column = INPUT_COLUMN[common.kind]
    items = []
    sources = []
    for k, row in enumerate(rows):
        where = f"{path} row {k + 1}"
        src = row.pop(column, None)
        if src in (None, ""):
            raise InputError(f"{where}: no '{column}' value")
        sources.append((path.parent / str(src)).resolve())
        model = row.pop("model", None)
        model = _model(path.parent / str(model) if model not in (None, "") else common.model, where)
        ident = row.pop("id", None)
        meta = tuple((m, str(row.pop(m))) for m in META_COLUMNS if row.get(m) not in (None, ""))
        options = {**common.options, **{k: v for k, v in row.items() if v not in (None, "")}}
        items.append((ident, model, meta, _option_pairs(options)))
    default_ids = _ids(sources)
    ids = unique(slug(str(i)) if i not in (None, "") else d for (i, *_), d in zip(items, default_ids, strict=True))
    return [Item(common.kind, i, model, str(src), options, meta)
            for i, (_, model, meta, options), src in zip(ids, items, sources, strict=True)]


def _manifest_rows(path: Path) -> list[dict]:
    try:
        if path.suffix == ".csv":
            text = read_text(path, MAX_MANIFEST_BYTES, "manifest")
            rows = [{k.strip(): (v or "").strip() for k, v in r.items() if k}
                    for r in csv.DictReader(io.StringIO(text, newline=""))]
        else:
            from elastic_pm_dyn.model import yaml12
            data = yaml12.load_file(path)
            rows = data.get("items") if isinstance(data, dict) else data
            if not isinstance(rows, list) or not all(isinstance(r, dict) for r in rows):
                raise InputError(f"{path}: a manifest is a list of mappings (or 'items:' holding one)")
            rows = [dict(r) for r in rows]
    except TextFileError as err:
        raise InputError(f"{path}: cannot read the manifest: {err.reason}") from None
    except (OSError, UnicodeDecodeError, csv.Error) as err:
        raise InputError(f"{path}: cannot read the manifest: {err}") from None
    except InputError:
        raise
    except Exception as err:  # a YAML syntax error: one line naming the file
        raise InputError(f"{path}: not a valid manifest: {' '.join(str(err).split())[:200]}") from None
    if not rows:
        raise InputError(f"{path}: the manifest has no rows")
    return rows
