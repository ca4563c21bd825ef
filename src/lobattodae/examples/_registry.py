"""Registry of the example problems under stable, CLI-friendly names."""

from __future__ import annotations

import types
from collections.abc import Callable, Mapping

from ._base import Example
from ._contact import contact_oscillator
from ._knife_edge import knife_edge
from ._particle import nonholonomic_particle
from ._rolling_disk import falling_rolling_disk, vertical_rolling_disk
from ._sleigh import chaplygin_sleigh

__all__ = ["EXAMPLES", "get_example", "list_examples"]


def _particle(**params) -> Example:
    """Free nonholonomic particle; see :func:`nonholonomic_particle`."""
    return nonholonomic_particle("free", **params)


def _particle_harmonic(**params) -> Example:
    """Nonholonomic particle in a harmonic potential; see :func:`nonholonomic_particle`."""
    return nonholonomic_particle("harmonic", **params)


def _falling_disk(**params) -> Example:
    """Steady circular rolling of the tilted disk; see :func:`falling_rolling_disk`."""
    return falling_rolling_disk(True, **params)


def _falling_disk_general(**params) -> Example:
    """General motion of the tilted rolling disk; see :func:`falling_rolling_disk`."""
    return falling_rolling_disk(False, **params)


def _contact(**params) -> Example:
    """Reversible contact oscillator; see :func:`contact_oscillator`."""
    return contact_oscillator(True, **params)


def _contact_nonreversible(**params) -> Example:
    """Non-reversible contact oscillator; see :func:`contact_oscillator`."""
    return contact_oscillator(False, **params)


_TABLE: dict[str, tuple[Callable[..., Example], str]] = {
    "particle": (_particle, "free nonholonomic particle z' = y x' (closed form)"),
    "particle-harmonic": (
        _particle_harmonic, "nonholonomic particle in a harmonic potential (long runs)"),
    "knife-edge": (knife_edge, "knife edge on an inclined plane (closed form)"),
    "sleigh": (chaplygin_sleigh, "Chaplygin sleigh (closed form up to a quadrature)"),
    "vertical-disk": (vertical_rolling_disk, "vertical rolling disk (closed form)"),
    "falling-disk": (
        _falling_disk, "tilted rolling disk, steady circular rolling (closed form)"),
    "falling-disk-general": (
        _falling_disk_general, "tilted rolling disk, general motion (long runs)"),
    "contact": (_contact, "McLachlan-Perlmutter contact oscillator (reversible)"),
    "contact-nonreversible": (
        _contact_nonreversible, "contact oscillator with S = cos z (not reversible)"),
}

#: Example name -> factory ``(**params) -> Example``; keyword parameters override the
#: defaults of PROBLEMS.md.
EXAMPLES: Mapping[str, Callable[..., Example]] = types.MappingProxyType(
    {name: factory for name, (factory, _) in _TABLE.items()}
)


def get_example(name: str, **params) -> Example:
    """Build the example registered as ``name``.

    Parameters
    ----------
    name : str
        One of :data:`EXAMPLES` (see :func:`list_examples`).
    **params
        Keyword parameters passed to the factory (physical parameters, initial data,
        ``t_end``).

    Returns
    -------
    Example
        The example, built by its factory (e.g. :func:`knife_edge`).

    Raises
    ------
    ValueError
        For an unknown name (the message lists the valid names), or a parameter the
        factory refuses.
    TypeError
        A keyword parameter the factory does not have.
    """
    try:
        factory = EXAMPLES[name]
    except (KeyError, TypeError):
        raise ValueError(
            f"unknown example {name!r}; valid names: {', '.join(EXAMPLES)}"
        ) from None
    return factory(**params)


def list_examples() -> list[tuple[str, str]]:
    """The registered examples, in a fixed order.

    Returns
    -------
    list of (str, str)
        ``(name, one-line description)`` for every name of :data:`EXAMPLES`.
    """
    return [(name, description) for name, (_, description) in _TABLE.items()]
