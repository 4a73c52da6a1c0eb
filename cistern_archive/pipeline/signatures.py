"""Check a plugin's methods against its stage's protocols once, at load (as pluggy checks a hook
implementation against its specification).

The runner calls every method of a protocol the same way: the protocol's positional parameters by
position, its keyword-only parameters by name. A plugin method must accept exactly that call: enough
positional parameters (or ``*args``), every keyword-only parameter of the protocol by name (or
``**kwargs``), and no parameter of its own without a default. Optional capabilities
(:data:`~cistern_archive.pipeline.contracts.CAPABILITIES`) are checked the same way once a plugin
implements them (:func:`check_methods`), and recorded in its
:class:`~cistern_archive.pipeline.registry.LoadedPlugin`.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from typing import Any

from cistern_archive.core.errors import PluginError
from cistern_archive.pipeline.contracts import CAPABILITIES, PROTOCOLS

METHODS = ("match", "pairs", "localize", "build", "compare", "guided_pairs", "echo_scale")
"""The methods the protocols define (the runner calls no other)."""

_POSITIONAL = (inspect.Parameter.POSITIONAL_ONLY, inspect.Parameter.POSITIONAL_OR_KEYWORD)


def protocol_methods(protocol: type) -> list[str]:
    """The methods ``protocol`` defines or inherits from another protocol, in :data:`METHODS` order."""
    return [m for m in METHODS if any(m in vars(k) for k in protocol.__mro__)]


def _spec(protocol: type, method: str) -> Callable[..., Any]:
    return next(vars(k)[method] for k in protocol.__mro__ if method in vars(k))


def _stubs() -> set[Any]:
    protocols = [*PROTOCOLS.values(), *(c for caps in CAPABILITIES.values() for c in caps)]
    return {vars(p)[m] for p in protocols for m in METHODS if m in vars(p)}


def signature_problem(spec: Callable[..., Any], impl: Callable[..., Any]) -> str:
    """What is wrong with ``impl`` (a bound method) as an implementation of ``spec`` (the protocol's
    function, with ``self``), or ``""``: a missing positional parameter, a keyword parameter it does not
    take or takes positionally only, or a parameter of its own without a default."""
    try:
        have = inspect.signature(impl).parameters
    except (TypeError, ValueError):
        return ""  # a builtin without a signature: nothing to check
    want = list(inspect.signature(spec).parameters.values())[1:]
    kinds = {p.kind for p in have.values()}
    positional = [p for p in have.values() if p.kind in _POSITIONAL]
    wanted_positional = [p.name for p in want if p.kind in _POSITIONAL]
    if inspect.Parameter.VAR_POSITIONAL not in kinds and len(positional) < len(wanted_positional):
        missing = wanted_positional[len(positional)]
        return (f"takes {len(positional)} positional parameter(s), the runner passes {len(wanted_positional)} "
                f"({', '.join(wanted_positional)}): parameter {missing!r} is missing")
    for p in (p for p in want if p.kind is inspect.Parameter.KEYWORD_ONLY):
        own = have.get(p.name)
        if own is None and inspect.Parameter.VAR_KEYWORD not in kinds:
            return f"does not take the keyword parameter {p.name!r}"
        if own is not None and own.kind is inspect.Parameter.POSITIONAL_ONLY:
            return f"takes parameter {p.name!r} by position only; the runner passes it by name"
    given = {p.name for p in want}
    for k, p in enumerate(have.values()):
        required = p.default is inspect.Parameter.empty and p.kind not in (
            inspect.Parameter.VAR_POSITIONAL, inspect.Parameter.VAR_KEYWORD)
        passed = p.name in given or (p.kind in _POSITIONAL and k < len(wanted_positional))
        if required and not passed:
            return f"has parameter {p.name!r} without a default, which the runner never passes"
    return ""


def check_methods(stage: str, name: str, instance: Any) -> frozenset[type]:
    """Check ``instance``'s methods against its stage's protocol and the capabilities it implements.

    A plugin implements a capability explicitly, by subclassing its protocol, or structurally, by
    defining what only the capability has (``guided_pairs``; a ``guess`` parameter of ``match``), as
    :class:`typing.Protocol` matches; either way every method of the capability must then have the
    protocol's signature.

    Returns
    -------
    frozenset of type
        The capabilities (protocols of :data:`CAPABILITIES`) the plugin implements.

    Raises
    ------
    PluginError
        Naming the plugin, the protocol, the method and what is wrong with it.
    """
    implemented = frozenset(c for c in CAPABILITIES.get(stage, ())
                            if c in type(instance).__mro__ or _structural_use(stage, c, instance))
    specs: dict[str, type] = {}  # method -> the most specific protocol that defines it
    for protocol in (PROTOCOLS[stage], *sorted(implemented, key=lambda c: c.__name__)):
        specs.update({method: protocol for method in protocol_methods(protocol)})
    stubs = _stubs()
    for method, protocol in specs.items():
        if inspect.getattr_static(type(instance), method, None) in stubs:
            raise PluginError(f"{stage} plugin {name!r} declares {protocol.__name__} but does not define {method}()")
        problem = signature_problem(_spec(protocol, method), getattr(instance, method))
        if problem:
            raise PluginError(f"{stage} plugin {name!r}: {method}() of {protocol.__name__} {problem}")
    return implemented


def _structural_use(stage: str, capability: type, instance: Any) -> bool:
    """Whether ``instance`` has a method or a parameter that only ``capability`` defines."""
    base = PROTOCOLS[stage]
    for method in protocol_methods(capability):
        if method not in protocol_methods(base):
            if callable(getattr(instance, method, None)):
                return True
            continue
        try:
            have = set(inspect.signature(getattr(instance, method)).parameters)
        except (TypeError, ValueError):
            continue
        own = set(inspect.signature(_spec(capability, method)).parameters)
        if (own - set(inspect.signature(_spec(base, method)).parameters)) & have:
            return True
    return False
