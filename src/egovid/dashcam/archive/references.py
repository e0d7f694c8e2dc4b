"""Reference chains: a joint segment is decoded against frames of the drive it was coded against,
that drive's joint segments against theirs, and so on down to root (intra) segments. A chain that
loops back (a damaged catalogue) can never be decoded; it is found here, not by a recursion."""

from __future__ import annotations

from collections.abc import Iterable

from egovid.core.errors import EgovidError
from egovid.dashcam.archive.catalogue_file import repair_fix


def reference_cycle(refs: dict[int, set[int]], start: int) -> list[int] | None:
    """A cycle reachable from drive ``start`` in the graph ``refs`` (drive -> drives its segments
    are coded against), as the list of drives around it; None when every chain ends at a root."""
    state: dict[int, int] = {}  # 1 = on the current path, 2 = done
    path: list[int] = []
    stack: list[tuple[int, Iterable[int]]] = [(start, iter(sorted(refs.get(start, ()))))]
    state[start] = 1
    path.append(start)
    while stack:
        node, children = stack[-1]
        child = next(children, None)  # type: ignore[call-overload]
        if child is None:
            stack.pop()
            path.pop()
            state[node] = 2
            continue
        if state.get(child) == 1:
            return [*path[path.index(child) :], child]
        if child not in state:
            state[child] = 1
            path.append(child)
            stack.append((child, iter(sorted(refs.get(child, ())))))
    return None


def check_chain(source, drive_id: int) -> None:
    """Raise :class:`EgovidError` when drive ``drive_id`` cannot be decoded because its reference
    chain (through ``source.segments``) loops back on itself (a self-reference included)."""
    refs: dict[int, set[int]] = {}
    todo = [int(drive_id)]
    while todo:
        d = todo.pop()
        if d in refs:
            continue
        refs[d] = {int(g.ref_drive_id) for g in source.segments(d) if g.ref_drive_id is not None}
        todo += [r for r in refs[d] if r not in refs]
    cycle = reference_cycle(refs, int(drive_id))
    if cycle:
        raise EgovidError(
            f"drive {drive_id} cannot be decoded: its references loop ({' -> '.join(map(str, cycle))})",
            f"the catalogue is damaged; {repair_fix(getattr(source, 'root', 'ARCHIVE'))} to see what is lost",
        )
