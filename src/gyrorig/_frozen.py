"""A read-only dict for the fields of frozen records."""

from __future__ import annotations

__all__ = ["FrozenDict"]


class FrozenDict(dict):
    """A dict that refuses changes.  Unlike ``types.MappingProxyType`` it pickles, so records holding one cross
    process boundaries (the Monte Carlo's workers), and ``json`` writes it as the dict it is."""

    __slots__ = ()

    def _refuse(self, *args, **kwargs):
        raise TypeError(f"{type(self).__name__} is read-only (the record it belongs to is frozen)")

    __setitem__ = __delitem__ = __ior__ = _refuse
    clear = pop = popitem = setdefault = update = _refuse

    def __reduce__(self):
        return (type(self), (dict(self),))

    def __repr__(self) -> str:
        return dict.__repr__(self)
