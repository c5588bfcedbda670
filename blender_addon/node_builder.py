"""A few lines of sugar for building node trees from Python (used by :mod:`.display`).

``NodeBuilder(tree)`` creates nodes in columns (each new node goes one step to the right
of the deepest node feeding it, so a built tree reads left to right in the editor) and
accepts either a socket or a constant wherever a node input is set.
"""

from __future__ import annotations

__all__ = ["NodeBuilder", "socket"]


def socket(sockets, key: str):
    """The first *enabled* socket named or identified ``key`` (typed nodes such as Mix or
    Compare keep one disabled copy per data type under the same name)."""
    for s in sockets:
        if s.identifier == key and s.enabled:
            return s
    for s in sockets:
        if s.name == key and s.enabled:
            return s
    raise KeyError(key)


class NodeBuilder:
    """Nodes and links of ``tree``; ``math``/``vmath`` return output sockets."""

    def __init__(self, tree, *, math_node: str = "ShaderNodeMath"):
        self.tree = tree
        self._math = math_node
        self._column: dict[str, int] = {}
        self._rows: dict[int, int] = {}

    def _place(self, node, depth: int) -> None:
        row = self._rows.get(depth, 0)
        self._rows[depth] = row + 1
        node.location = (220 * depth, -160 * row)
        self._column[node.name] = depth

    def _depth_of(self, value) -> int:
        node = getattr(value, "node", None)
        return self._column.get(node.name, 0) + 1 if node is not None else 0

    def set(self, node, key, value) -> None:
        """Link ``value`` (a socket) or set it (a constant) into ``node``'s input ``key``."""
        sock = node.inputs[key] if isinstance(key, int) else socket(node.inputs, key)
        if hasattr(value, "is_output"):
            self.tree.links.new(value, sock)
        else:
            sock.default_value = value

    def node(self, type_: str, inputs: dict | None = None, **props):
        """A new node of ``type_`` with ``props`` set first, then ``inputs``."""
        n = self.tree.nodes.new(type_)
        for k, v in props.items():
            setattr(n, k, v)
        inputs = inputs or {}
        self._place(n, max([self._depth_of(v) for v in inputs.values()], default=0))
        for k, v in inputs.items():
            self.set(n, k, v)
        return n

    def out(self, node, key=0):
        return node.outputs[key] if isinstance(key, int) else socket(node.outputs, key)

    def math(self, op: str, a, b=None, c=None):
        inputs = {0: a} if b is None else {0: a, 1: b}
        if c is not None:
            inputs[2] = c
        return self.node(self._math, inputs, operation=op).outputs[0]

    def vmath(self, op: str, a, b=None, c=None):
        inputs = {0: a} if b is None else {0: a, ("Scale" if op == "SCALE" else 1): b}
        if c is not None:
            inputs[2] = c
        n = self.node("ShaderNodeVectorMath", inputs, operation=op)
        return n.outputs["Value"] if op in ("DOT_PRODUCT", "DISTANCE", "LENGTH") else n.outputs[0]

    def link(self, a, b) -> None:
        self.tree.links.new(a, b)
