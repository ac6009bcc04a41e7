"""One shape check for numpy arrays and torch tensors: a wrong shape is one ValueError line."""

from __future__ import annotations


def check_shape(a, shape: tuple, what: str):
    """Return ``a`` if its shape matches ``shape``, else raise ValueError naming ``what``.

    ``shape`` holds an int (that size), a str (any size, named in the message: ``"B"``) and at most
    one ``...`` (any number of dimensions there). ``(..., 3)``: last axis 3; ``(4, 4)``: a 4x4 matrix.
    """
    got = tuple(a.shape)
    if ... in shape:
        i = shape.index(...)
        head, tail = shape[:i], shape[i + 1:]
        ok = len(got) >= len(head) + len(tail) and _fits(got[:len(head)], head) and _fits(got[len(got) - len(tail):], tail)
    else:
        ok = len(got) == len(shape) and _fits(got, shape)
    if not ok:
        spec = ", ".join("..." if s is ... else str(s) for s in shape)
        raise ValueError(f"{what} must have shape ({spec}{',' if len(shape) == 1 else ''}), got {got}")
    return a


def _fits(got: tuple, spec: tuple) -> bool:
    return all(isinstance(s, str) or g == s for g, s in zip(got, spec))
