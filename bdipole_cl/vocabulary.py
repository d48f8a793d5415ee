"""Option kinds as objects (the foundation layer): each allowed value of an option is an
``Option`` (its canonical name, what it means, the other spellings accepted for it), and each
kind of option has one ``Registry`` of them, defined once and imported by the API, the CLI,
scene files and the docs' checks (docs/python.md "Vocabulary").

The registries themselves live with what they name: the invalid-input policies in
``errors``, the models in ``physics.models``, the inversion and blur methods, borders, mfp
kinds and output groups in ``methods.registry``.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Generic, Iterator, TypeVar


@dataclass(frozen=True)
class Option:
    """One allowed value of an option: its canonical ``name``, a one-line ``summary`` and the
    other spellings (``aliases``) accepted for it."""

    name: str
    summary: str
    aliases: tuple = ()


T = TypeVar("T", bound=Option)


class Registry(Generic[T]):
    """The options of one kind (``kind``: the option's name, as in ``on_invalid=``), in their
    order: looked up by canonical name or alias."""

    def __init__(self, kind: str, options):
        self.kind = kind
        self.options = tuple(options)
        self.by_spelling = {}
        for option in self.options:
            for spelling in (option.name, *option.aliases):
                if spelling in self.by_spelling:
                    raise ValueError(f"{kind}: {spelling!r} names two options")
                self.by_spelling[spelling] = option

    @classmethod
    def of(cls, kind: str, **summaries: str) -> "Registry[Option]":
        """A registry of plain options, each ``name="summary"``, in the order given."""
        return cls(kind, (Option(name, summary) for name, summary in summaries.items()))

    @property
    def names(self) -> tuple:
        """The canonical names, in order."""
        return tuple(o.name for o in self.options)

    @property
    def spellings(self) -> tuple:
        """Every accepted spelling: each option's name, then its aliases."""
        return tuple(self.by_spelling)

    def __iter__(self) -> Iterator[T]:
        return iter(self.options)

    def __len__(self) -> int:
        return len(self.options)

    def __contains__(self, spelling) -> bool:
        return isinstance(spelling, str) and spelling in self.by_spelling

    def __getitem__(self, spelling) -> T:
        """The option ``spelling`` names; ValueError listing the choices if none."""
        if spelling not in self:
            raise ValueError(f"{self.kind}={spelling!r}: expected one of "
                             f"{', '.join(self.spellings)}")
        return self.by_spelling[spelling]

    def canonical(self, spelling) -> str:
        """The canonical name of ``spelling`` (ValueError if unknown)."""
        return self[spelling].name

    def listing(self, quote: str = "") -> str:
        """The accepted spellings for a message: 'a, b or c' (each in ``quote``)."""
        words = [f"{quote}{s}{quote}" for s in self.spellings]
        return " or ".join(words) if len(words) < 3 else ", ".join(words[:-1]) + " or " + words[-1]

    def __repr__(self) -> str:
        return f"Registry({self.kind!r}, {self.names})"
