"""Plain data to JSON and back, directed by the types: nothing is built that the type does not
name.

A message is a frozen dataclass (or a NamedTuple) whose fields are typed; encoding walks the
type, not the value: a dataclass is a JSON array of its fields in declaration order, a union
of several classes an array whose first item is the class's name (looked up among the
union's members only, never anywhere else), a tuple an array, a mapping an object with
string keys, an enumeration its value. Decoding checks every item against the type it must
be — a bool is not an int, an int fits in 64 bits, a float is finite, an array has the
length its class has — and says where it is wrong (``Frame.snapshot.alarms[2]: expected
...``). So bytes from a client can only ever become the few plain classes reachable from the
message type they are decoded as: no class name is ever looked up in a module, nothing is
executed, no object of another type is built.

A field a class declares with a type this cannot read (``Any`` beyond a plain scalar, a
class imported for type checking only) is named in ``overrides`` with the type it has on the
wire, or marked :data:`LOCAL`: not sent, given on decoding by the receiver (``fills``), as the
client fills a snapshot's layout from the project it loaded itself.

Each type's encoder and decoder are built once per codec and kept (a frame is encoded 20
times a second). :meth:`Codec.schema` describes the whole type tree as text: two processes
compare its digest before they talk, so a runtime and a screen of different versions refuse
each other in plain words instead of misreading each other's arrays.
"""

from __future__ import annotations

import dataclasses
import enum
import hashlib
import json
import math
import types
import typing
from collections.abc import Callable, Mapping
from typing import Any, Union

INT_MIN, INT_MAX = -(2 ** 63), 2 ** 63 - 1
SCALARS = (type(None), bool, int, float, str)


class WireError(ValueError):
    """Data that is not what its type says: where, and what was expected."""


class _Local:
    def __repr__(self) -> str:
        return "LOCAL"


LOCAL: Any = _Local()  # a field not sent: the receiver fills it (Codec(fills=...))

Encoder = Callable[[Any], Any]
Decoder = Callable[[Any, str], Any]


def _is_namedtuple(tp: Any) -> bool:
    return isinstance(tp, type) and issubclass(tp, tuple) and hasattr(tp, "_fields")


def _record_fields(cls: type) -> list[str]:
    if dataclasses.is_dataclass(cls):
        return [f.name for f in dataclasses.fields(cls)]
    return list(cls._fields)  # type: ignore[attr-defined]


def _hints(cls: type) -> dict[str, Any]:
    """The fields' types of a dataclass or a NamedTuple (for a NamedTuple subclass that only
    adds properties, its base's)."""
    source = cls
    if _is_namedtuple(cls) and "__annotations__" not in vars(cls):
        source = next(b for b in cls.__mro__[1:] if "__annotations__" in vars(b))
    try:
        return typing.get_type_hints(source)
    except NameError:  # a name imported for type checking only: overrides must say
        return {}


def _fail(path: str, expected: str, value: Any) -> WireError:
    shown = repr(value)
    if len(shown) > 60:
        shown = shown[:57] + "..."
    return WireError(f"{path or 'message'}: expected {expected}, got {shown}")


class Codec:
    """Encoders and decoders of typed plain data (module docstring).

    `overrides`: per class, field name -> the type it has on the wire, or LOCAL.
    `fills`: per class, field name -> a function giving a LOCAL field's value on decoding.
    `memo`: classes whose last value encoded is kept with its tree: the same object encoded
    again (one snapshot in every screen's frame) is not walked again."""

    def __init__(self, overrides: Mapping[type, Mapping[str, Any]] | None = None,
                 fills: Mapping[type, Mapping[str, Callable[[], Any]]] | None = None,
                 memo: tuple[type, ...] = ()):
        self.overrides = {cls: dict(fields) for cls, fields in (overrides or {}).items()}
        self.fills = {cls: dict(fields) for cls, fields in (fills or {}).items()}
        self.memo = memo
        self._encoders: dict[Any, Encoder] = {}
        self._decoders: dict[Any, Decoder] = {}

    # -- the public side -----------------------------------------------------------------
    def encode(self, value: Any, tp: Any) -> Any:
        """`value` (of type `tp`) as a tree of JSON values."""
        return self.encoder(tp)(value)

    def decode(self, data: Any, tp: Any, path: str = "") -> Any:
        """A tree of JSON values as a `tp`; WireError if it is not one."""
        return self.decoder(tp)(data, path)

    def dumps(self, value: Any, tp: Any) -> bytes:
        return json.dumps(self.encode(value, tp), ensure_ascii=False, allow_nan=False,
                          separators=(",", ":")).encode("utf-8")

    def loads(self, data: bytes, tp: Any) -> Any:
        try:
            tree = json.loads(data.decode("utf-8"), parse_constant=_no_constant)
        except (UnicodeDecodeError, json.JSONDecodeError, RecursionError, ValueError) as exc:
            raise WireError(f"not JSON: {type(exc).__name__}: {str(exc)[:120]}") from None
        return self.decode(tree, tp)

    def fields(self, cls: type) -> list[tuple[str, Any]]:
        """The fields of a class as the wire has them: (name, type or LOCAL)."""
        hints = _hints(cls)
        own = self.overrides.get(cls, {})
        found = []
        for name in _record_fields(cls):
            if name in own:
                found.append((name, own[name]))
            elif name in hints:
                found.append((name, hints[name]))
            else:
                raise TypeError(f"{cls.__qualname__}.{name}: its type cannot be read; "
                                "name it in the codec's overrides")
        return found

    def schema(self, tp: Any) -> str:
        """Every type reachable from `tp`, described as text (compared as a digest)."""
        seen: dict[str, str] = {}
        root = self._describe(tp, seen)
        return root + "\n" + "\n".join(f"{k} = {v}" for k, v in sorted(seen.items()))

    def schema_digest(self, tp: Any) -> str:
        return hashlib.blake2b(self.schema(tp).encode(), digest_size=12).hexdigest()

    # -- building them -------------------------------------------------------------------
    def encoder(self, tp: Any) -> Encoder:
        found = self._encoders.get(tp)
        if found is None:
            # (a placeholder first: a class reachable from itself, through its fields)
            self._encoders[tp] = lambda value: built(value)
            built = self._build_encoder(tp)
            self._encoders[tp] = found = built
        return found

    def decoder(self, tp: Any) -> Decoder:
        found = self._decoders.get(tp)
        if found is None:
            self._decoders[tp] = lambda data, path: built(data, path)
            built = self._build_decoder(tp)
            self._decoders[tp] = found = built
        return found

    def _build_encoder(self, tp: Any) -> Encoder:
        if tp is Any or tp in SCALARS:
            return _same
        origin = typing.get_origin(tp)
        args = typing.get_args(tp)
        if origin in (Union, types.UnionType):
            classes = [a for a in args if a is not type(None)]
            if all(a in SCALARS for a in classes):
                return _same
            if len(classes) == 1:
                inner = self.encoder(classes[0])
                return lambda value: None if value is None else inner(value)
            tagged = {cls: self._tagged_encoder(cls) for cls in classes}
            return lambda value: None if value is None else tagged[type(value)](value)
        if origin is tuple:
            if len(args) == 2 and args[1] is Ellipsis:
                item = self.encoder(args[0])
                if item is _same:
                    return list
                return lambda value: [item(v) for v in value]
            items = [self.encoder(a) for a in args]
            return lambda value: [f(v) for f, v in zip(items, value, strict=True)]
        if origin in (list, frozenset, set):
            item = self.encoder(args[0])
            return lambda value: [item(v) for v in value]
        if origin in (dict, Mapping) or tp in (dict, Mapping):
            inner = self.encoder(args[1]) if args else _same
            return lambda value: {str(k): inner(v) for k, v in value.items()}
        if isinstance(tp, type) and issubclass(tp, enum.Enum):
            return lambda value: value.value
        if isinstance(tp, type) and (dataclasses.is_dataclass(tp) or _is_namedtuple(tp)):
            if tp in self.memo:
                return _memoized(self._record_encoder(tp))
            return self._record_encoder(tp)
        raise TypeError(f"the wire cannot carry {tp!r}")

    def _record_encoder(self, cls: type) -> Encoder:
        getters = []
        for name, tp in self.fields(cls):
            if tp is LOCAL:
                continue
            getters.append((name, self.encoder(tp)))
        # (by attribute: a NamedTuple's property reads a field it stores lazily)
        return lambda value: [f(getattr(value, n)) for n, f in getters]

    def _tagged_encoder(self, cls: type) -> Encoder:
        inner = self.encoder(cls)
        name = cls.__name__
        return lambda value: [name, *inner(value)]

    def _build_decoder(self, tp: Any) -> Decoder:
        if tp is Any:
            return _scalar
        if tp in SCALARS:
            return _SCALAR_DECODERS[tp]
        origin = typing.get_origin(tp)
        args = typing.get_args(tp)
        if origin in (Union, types.UnionType):
            return self._union_decoder(args)
        if origin is tuple:
            if len(args) == 2 and args[1] is Ellipsis:
                item = self.decoder(args[0])

                def many(data: Any, path: str) -> Any:
                    if type(data) is not list:
                        raise _fail(path, "a list", data)
                    return tuple([item(v, f"{path}[{k}]") for k, v in enumerate(data)])
                return many
            items = [self.decoder(a) for a in args]
            count = len(items)

            def fixed(data: Any, path: str) -> Any:
                if type(data) is not list or len(data) != count:
                    raise _fail(path, f"a list of {count}", data)
                return tuple([f(v, f"{path}[{k}]") for k, (f, v) in
                              enumerate(zip(items, data, strict=True))])
            return fixed
        if origin in (list, frozenset, set):
            item = self.decoder(args[0])
            kind = origin

            def listed(data: Any, path: str) -> Any:
                if type(data) is not list:
                    raise _fail(path, "a list", data)
                return kind([item(v, f"{path}[{k}]") for k, v in enumerate(data)])
            return listed
        if origin in (dict, Mapping) or tp in (dict, Mapping):
            inner = self.decoder(args[1]) if args else _scalar
            proxy = origin is Mapping or tp is Mapping

            def mapped(data: Any, path: str) -> Any:
                if type(data) is not dict:
                    raise _fail(path, "an object", data)
                out = {k: inner(v, f"{path}.{k}") for k, v in data.items()}
                return types.MappingProxyType(out) if proxy else out
            return mapped
        if isinstance(tp, type) and issubclass(tp, enum.Enum):
            members = {m.value: m for m in tp}

            def enumerated(data: Any, path: str) -> Any:
                try:
                    return members[data]
                except (KeyError, TypeError):
                    raise _fail(path, f"one of {sorted(map(str, members))}", data) from None
            return enumerated
        if isinstance(tp, type) and (dataclasses.is_dataclass(tp) or _is_namedtuple(tp)):
            return self._record_decoder(tp)
        raise TypeError(f"the wire cannot carry {tp!r}")

    def _union_decoder(self, args: tuple[Any, ...]) -> Decoder:
        optional = type(None) in args
        classes = [a for a in args if a is not type(None)]
        if all(a in SCALARS for a in classes):
            allowed = tuple(classes) + ((type(None),) if optional else ())
            names = " or ".join(a.__name__ for a in allowed)
            whole_as_float = float in allowed and int not in allowed

            def scalars(data: Any, path: str) -> Any:
                kind = type(data)
                if kind is int and whole_as_float:
                    return _float(data, path)
                if kind not in allowed:
                    raise _fail(path, names, data)
                return _SCALAR_DECODERS[kind](data, path)
            return scalars
        if len(classes) == 1:
            inner = self.decoder(classes[0])

            def maybe(data: Any, path: str) -> Any:
                return None if data is None and optional else inner(data, path)
            return maybe
        by_name = {cls.__name__: self.decoder(cls) for cls in classes}
        names = ", ".join(by_name)

        def tagged(data: Any, path: str) -> Any:
            if data is None and optional:
                return None
            if type(data) is not list or not data or type(data[0]) is not str:
                raise _fail(path, f"[name, ...] of one of {names}", data)
            inner = by_name.get(data[0])
            if inner is None:
                raise _fail(path, f"one of {names}", data[0])
            return inner(data[1:], f"{path}<{data[0]}>")
        return tagged

    def _record_decoder(self, cls: type) -> Decoder:
        wire: list[tuple[str, Decoder]] = []
        local: list[tuple[str, Callable[[], Any]]] = []
        fills = self.fills.get(cls, {})
        order = _record_fields(cls)
        for name, tp in self.fields(cls):
            if tp is LOCAL:
                local.append((name, fills.get(name) or _unfilled(cls, name)))
            else:
                wire.append((name, self.decoder(tp)))
        count = len(wire)
        label = cls.__name__
        positional = _is_namedtuple(cls)

        def record(data: Any, path: str) -> Any:
            if type(data) is not list or len(data) != count:
                raise _fail(path, f"{label} as a list of {count}", data)
            values = {name: f(v, f"{path}.{name}") for (name, f), v in
                      zip(wire, data, strict=True)}
            for name, fill in local:
                values[name] = fill()
            try:
                if positional:
                    return tuple.__new__(cls, [values[n] for n in order])
                return cls(**values)
            except (TypeError, ValueError) as exc:  # a class's own check of its values
                raise WireError(f"{path or label}: {exc}") from None
        return record

    def _describe(self, tp: Any, seen: dict[str, str]) -> str:
        if tp is Any:
            return "any"
        if tp in SCALARS:
            return "null" if tp is type(None) else tp.__name__
        origin = typing.get_origin(tp)
        args = typing.get_args(tp)
        if origin in (Union, types.UnionType):
            return "(" + " | ".join(self._describe(a, seen) for a in args) + ")"
        if origin is tuple:
            if len(args) == 2 and args[1] is Ellipsis:
                return f"[{self._describe(args[0], seen)}...]"
            return "[" + ", ".join(self._describe(a, seen) for a in args) + "]"
        if origin in (list, frozenset, set):
            return f"[{self._describe(args[0], seen)}...]"
        if origin in (dict, Mapping) or tp in (dict, Mapping):
            return "{" + (self._describe(args[1], seen) if args else "any") + "}"
        if isinstance(tp, type) and issubclass(tp, enum.Enum):
            return f"{tp.__name__}<{','.join(str(m.value) for m in tp)}>"
        if isinstance(tp, type):
            name = tp.__qualname__
            if name not in seen:
                seen[name] = "..."
                seen[name] = "(" + ", ".join(
                    f"{n}: {'local' if t is LOCAL else self._describe(t, seen)}"
                    for n, t in self.fields(tp)) + ")"
            return name
        raise TypeError(f"the wire cannot carry {tp!r}")


def _same(value: Any) -> Any:
    return value


def _unfilled(cls: type, name: str) -> Callable[[], Any]:
    def fail() -> Any:
        raise WireError(f"{cls.__qualname__}.{name} is not sent, and this codec was given "
                        "nothing to fill it with")
    return fail


def _memoized(encode: Encoder) -> Encoder:
    last: tuple[Any, Any] = (None, None)

    def memo(value: Any) -> Any:
        nonlocal last
        held, tree = last
        if held is value:
            return tree
        tree = encode(value)
        last = (value, tree)  # (one assignment: a reader in another thread sees a pair)
        return tree
    return memo


def _no_constant(name: str) -> Any:
    raise ValueError(f"{name} is not a number JSON has")


def _scalar(data: Any, path: str) -> Any:
    kind = type(data)
    if kind not in SCALARS:
        raise _fail(path, "a plain value (null, true/false, a number, a string)", data)
    return _SCALAR_DECODERS[kind](data, path)


def _none(data: Any, path: str) -> Any:
    if data is not None:
        raise _fail(path, "null", data)
    return None


def _bool(data: Any, path: str) -> Any:
    if type(data) is not bool:
        raise _fail(path, "true or false", data)
    return data


def _int(data: Any, path: str) -> Any:
    if type(data) is not int or not INT_MIN <= data <= INT_MAX:
        raise _fail(path, "a whole number (64 bits)", data)
    return data


def _float(data: Any, path: str) -> Any:
    if type(data) is int and INT_MIN <= data <= INT_MAX:
        return float(data)
    if type(data) is not float or not math.isfinite(data):
        raise _fail(path, "a number", data)
    return data


def _str(data: Any, path: str) -> Any:
    if type(data) is not str:
        raise _fail(path, "a string", data)
    return data


_SCALAR_DECODERS: dict[type, Decoder] = {type(None): _none, bool: _bool, int: _int,
                                         float: _float, str: _str}
