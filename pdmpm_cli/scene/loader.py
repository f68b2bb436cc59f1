"""Load a YAML scene file into a pydantic model, reporting every problem as `file:line:col key: message`.

Generic over the model class: all knowledge of the schema comes from pydantic's errors and `model_fields`.
The work is bounded before it can grow: files over MAX_BYTES are refused unread, the composer counts nodes
and nesting (MAX_NODES, MAX_DEPTH), building the data counts every alias expansion against the same node
budget (a "billion laughs" file stops at the first alias past it), and at most MAX_SHOWN problems are printed.
"""

from __future__ import annotations

import copy
import difflib
import json
import os
import re
import types
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Annotated, Any, Literal, TypeVar, Union, get_args, get_origin

import yaml
from pydantic import BaseModel, ValidationError
from yaml.composer import Composer
from yaml.constructor import SafeConstructor
from yaml.resolver import Resolver

from pdmpm_cli.errors import InputError

OVERRIDE = "--set"
_SET_FORM = "expected KEY=VALUE, e.g. --set bodies.0.material.mu=2e5"
MAX_BYTES = 1 << 20  # a scene file is hand-written: the bundled ones are under 10 KiB
MAX_NODES = 100_000  # YAML nodes, every alias expansion counted: 100x the largest bundled scene
MAX_DEPTH = 64  # nesting levels of mappings and lists (scenes use about 8)
MAX_SHOWN = 20  # problems printed; the rest are counted
_CONVERTED = 500  # pydantic errors turned into located problems (each costs a walk of the schema)
_FLOAT, _BOOL = "tag:yaml.org,2002:float", "tag:yaml.org,2002:bool"
_SEQUENCES = (list, tuple, set, frozenset, Sequence)

DataPath = tuple[Union[str, int], ...]  # str keys into mappings, int indices into lists
Mark = tuple[int, int]  # (line, col), 1-based
M = TypeVar("M", bound=BaseModel)


@dataclass(frozen=True)
class Problem:
    """One thing wrong with the input, pointing at where the user can fix it."""

    file: str
    line: int | None
    col: int | None
    key: str
    message: str

    def __str__(self) -> str:
        where = self.file if self.line is None else f"{self.file}:{self.line}:{self.col}"
        return f"{where} {self.key}: {self.message}" if self.key else f"{where}: {self.message}"


class SceneError(InputError):
    """Every problem found in the scene and its overrides, so the user can fix them all in one go; the first
    MAX_SHOWN are printed and the rest counted (`more` counts problems found but not located)."""

    def __init__(self, problems: list[Problem], more: int = 0):
        self.problems = list(problems)
        hidden = len(self.problems) - MAX_SHOWN + more if len(self.problems) > MAX_SHOWN else more
        lines = list(map(str, self.problems[:MAX_SHOWN]))
        if hidden > 0:
            lines.append(f"... and {hidden} more problems (fix the ones above and validate again)")
        super().__init__("\n".join(lines))


def _fail(file: str, message: str, key: str = "", mark: Mark | None = None) -> SceneError:
    return SceneError([Problem(file, *(mark or (None, None)), key, message)])


class _TooBig(yaml.MarkedYAMLError):
    """The composer stopped: too many nodes or too deep."""


class _BoundedComposer(Composer):
    """PyYAML's composer with a node count and a nesting depth, checked before each node is built."""

    def compose_document(self):
        self._nodes, self._depth = 0, 0
        return super().compose_document()

    def compose_node(self, parent, index):
        self._nodes += 1
        if self._nodes > MAX_NODES or self._depth >= MAX_DEPTH:
            what = (f"nested deeper than {MAX_DEPTH} levels" if self._depth >= MAX_DEPTH else
                    f"more than {MAX_NODES:,} YAML nodes; a scene is a short hand-written file")
            raise _TooBig(problem=what, problem_mark=self.peek_event().start_mark)
        self._depth += 1
        node = super().compose_node(parent, index)
        self._depth -= 1
        return node


class _Loader(_BoundedComposer, yaml.SafeLoader):
    """SafeLoader with YAML 1.2 floats and booleans and a bounded composer.

    PyYAML follows YAML 1.1, where `1e5` is a string (only `1.0e+5` is a float) and `no`/`on`/`yes`
    are booleans (so `name: no` would become False). Here every float a user writes is a float and
    only true/false are booleans; pydantic still accepts "yes"/"on" for boolean fields.
    """

    yaml_implicit_resolvers = {
        ch: [r for r in rs if r[0] not in (_FLOAT, _BOOL)]
        for ch, rs in yaml.SafeLoader.yaml_implicit_resolvers.items()
    }


_Loader.add_implicit_resolver(_BOOL, re.compile(r"^(?:true|True|TRUE|false|False|FALSE)$"), list("tTfF"))

_Loader.add_implicit_resolver(
    _FLOAT,
    re.compile(
        r"""^(?:[-+]?[0-9][0-9_]*\.[0-9_]*(?:[eE][-+]?[0-9]+)?
        |[-+]?\.[0-9][0-9_]*(?:[eE][-+]?[0-9]+)?
        |[-+]?[0-9][0-9_]*[eE][-+]?[0-9]+
        |[-+]?[0-9][0-9_]*(?::[0-5]?[0-9])+\.[0-9_]*
        |[-+]?\.(?:inf|Inf|INF)
        |\.(?:nan|NaN|NAN))$""",
        re.X,
    ),
    list("-+0123456789."),
)


try:
    from yaml._yaml import CParser

    class _FastLoader(_BoundedComposer, CParser, SafeConstructor, Resolver):
        """The same loader on libyaml's parser (about 3x faster). Its syntax messages are terser, so a file it
        refuses is parsed again by _Loader for the message."""

        yaml_implicit_resolvers = _Loader.yaml_implicit_resolvers

        def __init__(self, stream):
            CParser.__init__(self, stream)
            Composer.__init__(self)
            SafeConstructor.__init__(self)
            Resolver.__init__(self)
except ImportError:  # PyYAML built without libyaml
    _FastLoader = _Loader


def _dotted(path) -> str:
    return ".".join(map(str, path))


def _pos(node: yaml.Node) -> Mark:
    return node.start_mark.line + 1, node.start_mark.column + 1


def _did_you_mean(word: Any, options: list[str]) -> str:
    close = difflib.get_close_matches(str(word), options, n=1)
    return f"did you mean {close[0]}?" if close else ""


# ---------------------------------------------------------------- YAML -> data with positions


class _Tree:
    """Plain data built from the YAML node tree, remembering where every key and value was written.

    `marks[path]` is a scalar's position, or for a mapping/list the position of the key naming it
    (that line reads best in a message); `key_marks[path]` is the key's position.
    """

    def __init__(self, file: str, text: str):
        self.file, self.marks, self.key_marks = file, {}, {}
        self.problems: list[Problem] = []
        self._open: set[int] = set()
        self._built = 0
        try:
            root = self._compose(text)
        except _TooBig as e:
            raise _fail(file, f"{e.problem}", mark=(e.problem_mark.line + 1, e.problem_mark.column + 1)) from None
        except yaml.MarkedYAMLError as e:
            msg = f"invalid YAML: {e.problem}"
            if e.context and e.context_mark:
                msg += f" ({e.context} on line {e.context_mark.line + 1})"
            if "'\\t'" in str(e.problem):
                msg += "; indent with spaces, not tabs"
            raise _fail(file, msg, mark=(e.problem_mark.line + 1, e.problem_mark.column + 1)) from None
        except yaml.YAMLError as e:  # the reader's errors (control characters) carry only an offset
            at = getattr(e, "position", None)
            mark = None if at is None else (text.count("\n", 0, at) + 1, at - text.rfind("\n", 0, at))
            raise _fail(file, f"invalid YAML: {str(e).splitlines()[0]}", mark=mark) from None
        if root is None:
            raise _fail(file, "file is empty (expected a mapping of scene settings, e.g. 'bodies:')")
        if not isinstance(root, yaml.MappingNode):
            kind = "a list" if isinstance(root, yaml.SequenceNode) else f"the value {root.value!r}"
            raise _fail(file, f"top level must be a mapping of keys (e.g. 'bodies:'), found {kind}", mark=_pos(root))
        self.data = self._build(root, ())
        if self.problems:
            raise SceneError(self.problems)

    def _compose(self, text: str) -> yaml.Node | None:
        """The node tree, from libyaml when it reads the file; a file it refuses is read again for the message."""
        try:
            self._loader = _FastLoader(text)
            return self._loader.get_single_node()
        except _TooBig:
            raise
        except yaml.YAMLError:
            if _FastLoader is _Loader:
                raise
        self._loader = _Loader(text)
        return self._loader.get_single_node()

    def _problem(self, path: DataPath, mark: Mark, message: str) -> None:
        self.problems.append(Problem(self.file, *mark, _dotted(path), message))

    def _build(self, node: yaml.Node, path: DataPath) -> Any:
        if id(node) in self._open:
            return self._problem(path, _pos(node), "alias refers to itself")
        self._built += 1
        if self._built > MAX_NODES or len(path) > MAX_DEPTH:
            what = (f"aliases expand to more than {MAX_NODES:,} YAML nodes" if self._built > MAX_NODES else
                    f"aliases nest deeper than {MAX_DEPTH} levels")
            raise _fail(self.file, f"{what}; write the values out or use fewer aliases", _dotted(path), _pos(node))
        if isinstance(node, yaml.ScalarNode):
            try:
                return self._loader.construct_object(node)
            except (yaml.YAMLError, ValueError) as e:
                problem = getattr(e, "problem", e)
                return self._problem(path, _pos(node), f"cannot read value {node.value!r}: {problem}")
        self._open.add(id(node))
        if isinstance(node, yaml.SequenceNode):
            out: Any = []
            for i, item in enumerate(node.value):
                self.marks[path + (i,)] = _pos(item)
                out.append(self._build(item, path + (i,)))
        else:
            out = {}
            for knode, vnode in node.value:
                if knode.tag == "tag:yaml.org,2002:merge" or not isinstance(knode, yaml.ScalarNode):
                    self._problem(path, _pos(knode), "keys must be plain names (merge keys '<<' are not supported)")
                    continue
                sub = path + (knode.value,)
                if knode.value in out:
                    self._problem(sub, _pos(knode), f"duplicate key (first written on line {self.key_marks[sub][0]})")
                    continue
                self.key_marks[sub] = _pos(knode)
                self.marks[sub] = _pos(vnode if isinstance(vnode, yaml.ScalarNode) else knode)
                out[knode.value] = self._build(vnode, sub)
        self._open.discard(id(node))
        return out

    def where(self, path: DataPath, key: bool = False) -> Mark | None:
        """Position of `path` (of its key if `key`), else of the nearest enclosing thing the file has."""
        if key and path in self.key_marks:
            return self.key_marks[path]
        for i in range(len(path), 0, -1):
            if path[:i] in self.marks:
                return self.marks[path[:i]]
        return None


# ---------------------------------------------------------------- overrides


def _segments(parts: list[str]) -> list[str | int]:
    """The parts of a dotted key, with digits as list indices: ['bodies', '0', 'mu'] -> ['bodies', 0, 'mu']."""
    return [int(s) if re.fullmatch(r"[0-9]+", s) else s for s in parts]


def parse_overrides(items: list[str]) -> list[tuple[list[str | int], object]]:
    """Parse `a.b.0.c=value` items; the value is YAML (`1e5`, `[1, 2, 3]`, `{model: elastic}`)."""
    out, problems = [], []
    for item in items:
        key, sep, text = item.partition("=")
        segs = key.strip().split(".")
        if not sep or not all(segs):
            problems.append(Problem(OVERRIDE, None, None, "", f"malformed override {item!r} ({_SET_FORM})"))
            continue
        try:
            value = yaml.load(text, Loader=_Loader)
        except yaml.YAMLError as e:
            message = f"cannot read value {text!r} as YAML: {getattr(e, 'problem', e)}"
            problems.append(Problem(OVERRIDE, None, None, key.strip(), message))
            continue
        out.append((_segments(segs), value))
    if problems:
        raise SceneError(problems)
    return out


def _apply(data: dict, keys: list[str | int], value: object, source: str = OVERRIDE,
           mark: Mark | None = None) -> DataPath:
    """Set one override, creating missing mappings on the way; return the path it set."""
    node, path, key = data, (), _dotted(keys)
    for i, seg in enumerate(keys):
        if isinstance(node, list):
            if not isinstance(seg, int):
                raise _fail(source, f"{_dotted(path)} is a list; use an item number, e.g. {_dotted(path)}.0", key,
                            mark)
            if seg >= len(node):
                raise _fail(source, f"index {seg} is past the end of {_dotted(path)} (it has {len(node)} items)", key,
                            mark)
        elif isinstance(node, dict):
            seg = str(seg)
        else:
            raise _fail(source, f"{_dotted(path)} is {node!r}, not a mapping or list", key, mark)
        path += (seg,)
        if i == len(keys) - 1:
            node[seg] = value
        else:
            if isinstance(node, dict) and node.get(seg) is None:
                node[seg] = {}
            node = node[seg]
    return path


# ---------------------------------------------------------------- walking the model's annotations


def _is_model(tp: Any) -> bool:
    return isinstance(tp, type) and issubclass(tp, BaseModel)


def _disc_name(d: Any) -> str | None:
    """The field name of a `Field(discriminator=...)` / `Discriminator(...)`; None for callables."""
    d = getattr(d, "discriminator", d)
    return d if isinstance(d, str) else None


def _unwrap(tp: Any, disc: str | None = None) -> tuple[Any, str | None]:
    while get_origin(tp) is Annotated:
        tp, *meta = get_args(tp)
        disc = next((d for m in meta if (d := _disc_name(getattr(m, "discriminator", None)))), disc)
    return tp, disc


def _keys(model: type[BaseModel]) -> list[str]:
    return [f.alias or name for name, f in model.model_fields.items()]


def _is_union(tp: Any) -> bool:
    return get_origin(tp) in (Union, types.UnionType)


def _tags(tp: Any, disc: str) -> list[str]:
    """Allowed discriminator values of a union (or of one model)."""
    tp, _ = _unwrap(tp)
    if _is_union(tp):
        return [t for a in get_args(tp) for t in _tags(a, disc)]
    field = tp.model_fields.get(disc) if _is_model(tp) else None
    is_literal = field is not None and get_origin(field.annotation) is Literal
    return [str(t) for t in get_args(field.annotation)] if is_literal else []


def _member(tp: Any, disc: str | None, node: Any) -> Any:
    """The member of a (possibly Optional or discriminated) union that applies to the data `node`."""
    tp, disc = _unwrap(tp, disc)
    if not _is_union(tp):
        return tp
    options = [a for a in get_args(tp) if a is not type(None)]
    if disc and isinstance(node, dict):
        options = [a for a in options if str(node.get(disc)) in _tags(a, disc)] or options
    if isinstance(node, dict):
        models = [a for a in options if _is_model(_unwrap(a)[0])]
        options = sorted(models, key=lambda m: -len(node.keys() & set(_keys(_unwrap(m)[0])))) or options
    elif isinstance(node, list):
        options = [a for a in options if get_origin(_unwrap(a)[0]) in _SEQUENCES] or options
    return _member(options[0], None, node) if len(options) == 1 or isinstance(node, dict) else None


def _tagged(tp: Any, disc: str | None, seg: Any) -> Any:
    """The union member that pydantic names by `seg` in an error's loc (its tag or class name), else None."""
    if not _is_union(tp) or not isinstance(seg, str):
        return None
    for member in get_args(tp):
        model = _unwrap(member)[0]
        if (disc and seg in _tags(model, disc)) or (_is_model(model) and seg == model.__name__):
            return member
    return None


def _field_type(tp: Any, seg: Any) -> tuple[Any, str | None]:
    """Annotation (and discriminator) of item `seg` inside a value of type `tp`; (None, None) if unknown."""
    origin, args = get_origin(tp), get_args(tp)
    if _is_model(tp):
        field = next((f for name, f in tp.model_fields.items() if seg in (name, f.alias)), None)
        return _unwrap(field.annotation, _disc_name(field.discriminator)) if field else (None, None)
    if origin is tuple and args and args[-1] is not Ellipsis:
        return _unwrap(args[seg]) if isinstance(seg, int) and seg < len(args) else (None, None)
    if origin in _SEQUENCES and args:
        return _unwrap(args[0])
    if origin in (dict, Mapping) and len(args) == 2:
        return _unwrap(args[1])
    return None, None


_ABSENT = object()


def _walk(model_cls: type[BaseModel], data: Any, loc: tuple, missing: bool = False) -> tuple[DataPath, Any, Any, Any]:
    """Follow a pydantic `loc` through the data and the annotations.

    Returns (path as written in YAML, annotation and discriminator there, data there). pydantic puts
    union tags into `loc` (`bodies.0.geometry.box.size`); they pick the member and are left out of the path.
    """
    tp, disc, node, path = model_cls, None, data, ()
    for i, seg in enumerate(loc):
        tp, disc = _unwrap(tp, disc)
        if (member := _tagged(tp, disc, seg)) is not None:
            tp, disc = _unwrap(member)
            continue
        if isinstance(node, dict) and seg in node:
            child = node[seg]
        elif isinstance(node, list) and type(seg) is int and seg < len(node):
            child = node[seg]
        elif missing and i == len(loc) - 1:
            child = _ABSENT
        else:
            continue  # a tag for a union member that is not a model ('float', 'function-after[...]')
        tp, disc = _field_type(_member(tp, disc, node), seg)
        path, node = path + (seg,), child
    return path, tp, disc, node


def _show(value: Any) -> str:
    return json.dumps(value) if value is None or isinstance(value, bool) else repr(value)


def _explain(err: dict, model_cls: type[BaseModel], data: Any) -> tuple[DataPath, str, str]:
    """(path to report, where to point: 'key'/'parent'/'value', plain-words message) for one pydantic error."""
    kind, got, loc = err["type"], err.get("input"), err["loc"]
    path, tp, disc, node = _walk(model_cls, data, loc, missing=kind == "missing")
    if kind == "missing" and path and isinstance(path[-1], int):  # a fixed-length tuple given too few items
        path, tp, disc, node = _walk(model_cls, data, loc[:-1])
        tp = _member(tp, disc, node)
        wanted = f"must have {len(get_args(tp))} items" if get_origin(tp) is tuple else "too few items"
        return path, "value", f"{wanted} (got {_show(node)})"
    if kind == "missing":
        return path, "parent", "missing required key"
    if kind == "extra_forbidden":
        model = _member(*_walk(model_cls, data, loc[:-1])[1:])
        allowed = _keys(model) if _is_model(model) else []
        hint = _did_you_mean(path[-1], allowed) or (f"allowed keys: {', '.join(allowed)}" if allowed else "")
        return path, "key", f"unknown key ({hint})" if hint else "unknown key"
    if kind in ("union_tag_invalid", "union_tag_not_found"):
        disc = err["ctx"]["discriminator"].strip("'")
        tags = _tags(tp, disc)
        expected = f"expected one of: {', '.join(tags)}" if tags else ""
        if kind == "union_tag_not_found":
            return path + (disc,), "parent", f"missing {disc}" + (f" ({expected})" if expected else "")
        tag = err["ctx"]["tag"]
        hint = "; ".join(h for h in (expected, _did_you_mean(tag, tags)) if h)
        return path + (disc,), "value", f"unknown {disc} {tag!r}" + (f" ({hint})" if hint else "")
    msg = err["msg"].removeprefix("Value error, ").removeprefix("Assertion failed, ")
    msg = "must be " + msg.removeprefix("Input should be ") if msg.startswith("Input should be ") else msg
    if kind == "finite_number":
        msg += ", not .inf or .nan"
    if not isinstance(got, dict) and len(_show(got)) <= 40:
        extra = [f"got {_show(got)}"]
        tp = _member(tp, disc, got)
        if kind == "literal_error" and get_origin(tp) is Literal:
            extra.append(_did_you_mean(got, [str(a) for a in get_args(tp)]))
        msg += f" ({'; '.join(e for e in extra if e)})"
    return path, "value", msg


def _problem(err: dict, model_cls: type[BaseModel], tree: _Tree,
             set_paths: list[tuple[DataPath, str, Mark | None]]) -> Problem:
    """Turn one pydantic error into a Problem located in the file, or at the --set (or variant line) that put the
    value there. `set_paths` holds (path set, where it came from, its mark or None)."""
    path, how, message = _explain(err, model_cls, tree.data)
    anchor = path[:-1] if how == "parent" else path
    for sp, source, mark in reversed(set_paths):
        inside = path[: len(sp)] == sp
        created = anchor and sp[: len(anchor)] == anchor and anchor not in tree.marks
        if inside or created:
            return Problem(source, *(mark or (None, None)), _dotted(path), message)
    if how == "value" and (within := [f"{'--set' if source == OVERRIDE else 'the variant'} {_dotted(sp)}"
                                      for sp, source, _ in set_paths if sp[: len(path)] == path]):
        message += f" (with {', '.join(within)})"  # a model's own check may fail because of an override
    mark = tree.where(anchor, key=how == "key")
    return Problem(tree.file, *(mark or (None, None)), _dotted(path), message)


# ---------------------------------------------------------------- entry point


def _read(path: str | os.PathLike, file: str) -> str:
    try:
        with open(path, "rb") as f:
            raw = f.read(MAX_BYTES + 1)
    except FileNotFoundError:
        raise _fail(file, f"file not found (relative paths start from the current directory, {os.getcwd()})") from None
    except IsADirectoryError:
        raise _fail(file, "is a directory; give the path of a YAML scene file") from None
    except OSError as e:
        raise _fail(file, f"cannot read file: {e.strerror or e}") from None
    if len(raw) > MAX_BYTES:
        raise _fail(file, f"larger than {MAX_BYTES // 1024} KiB; a scene is a short hand-written file (meshes go in "
                          f"their own files, named by geometry.shape.path)")
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as e:
        line_start = raw.rfind(b"\n", 0, e.start) + 1
        mark = (raw.count(b"\n", 0, e.start) + 1, e.start - line_start + 1)
        raise _fail(file, f"not UTF-8 text (byte 0x{raw[e.start]:02x}); save the file as UTF-8", mark=mark) from None


def _variant_edits(tree: _Tree, name: str) -> list[tuple[list[str | int], object, Mark | None]]:
    """The overrides of the scene's top-level `variants.<name>` mapping (dotted key: value, as --set), each with
    the position of its line."""
    variants = tree.data.get("variants") or {}
    if not isinstance(variants, dict) or name not in variants:
        names = list(variants) if isinstance(variants, dict) else []
        where = tree.marks.get(("variants",))
        defined = f"it defines {', '.join(names)}" if names else "it defines none (add a top-level 'variants:' mapping)"
        hint = _did_you_mean(name, names)
        raise _fail(tree.file, f"no variant {name!r}{f' ({hint})' if hint else ''}; {defined}", "variants", where)
    edits = variants[name]
    if not isinstance(edits, dict):
        raise _fail(tree.file, "a variant is a mapping of dotted keys to values, e.g. bodies.0.material.mu: 2.0e4",
                    f"variants.{name}", tree.marks.get(("variants", name)))
    return [(_segments(str(key).split(".")), value, tree.marks.get(("variants", name, key)))
            for key, value in edits.items()]


def load_scene(path: str | os.PathLike, model_cls: type[M], overrides: Sequence[str] = (),
               variant: str | None = None) -> tuple[M, str]:
    """Read, parse, override and validate a scene; return (model instance, file text) or raise SceneError.

    A `variant` applies the scene's own `variants.<variant>` overrides first; `overrides` (--set) win over it."""
    file = str(path)
    edits = parse_overrides(list(overrides))
    text = _read(path, file)
    tree = _Tree(file, text)
    set_paths = _edit(tree, edits, variant)
    try:
        return model_cls.model_validate(tree.data), text
    except ValidationError as e:
        errors = e.errors(include_url=False)
        problems = {str(p): p for p in (_problem(err, model_cls, tree, set_paths) for err in errors[:_CONVERTED])}
        order = lambda p: (p.file == OVERRIDE, p.line or 0, p.col or 0)  # noqa: E731
        raise SceneError(sorted(problems.values(), key=order), more=max(0, len(errors) - _CONVERTED)) from None


def _edit(tree: _Tree, edits, variant: str | None) -> list[tuple[DataPath, str, Mark | None]]:
    """Apply the variant's overrides, then --set's, to the tree's data; return (path set, source, mark) of each."""
    set_paths = []
    if variant is not None:
        set_paths = [(_apply(tree.data, keys, value, tree.file, mark), tree.file, mark)
                     for keys, value, mark in _variant_edits(tree, variant)]
    return set_paths + [(_apply(tree.data, keys, value), OVERRIDE, None) for keys, value in edits]


def locate(error, path: str | os.PathLike, text: str, overrides: Sequence[str] = (),
           variant: str | None = None) -> InputError:
    """A SceneValueError (bad input found past the schema: a broken mesh file, a body larger than the domain) as a
    SceneError pointing at its key's line in the scene file, or at the --set or variant line that set it."""
    if not error.key:
        return error
    tree = _Tree(str(path), text)
    key = tuple(error.key)
    for sp, source, mark in reversed(_edit(tree, parse_overrides(list(overrides)), variant)):
        if key[: len(sp)] == sp:
            return SceneError([Problem(source, *(mark or (None, None)), _dotted(key), error.message)])
    return SceneError([Problem(tree.file, *(tree.where(key) or (None, None)), _dotted(key), error.message)])


def merge(base: dict, changes: dict) -> dict:
    """Deep merge of nested scene dicts; lists and scalars in `changes` replace."""
    out = copy.deepcopy(base)
    for k, v in changes.items():
        out[k] = merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out
