"""The packages' import graph, read from the source with :mod:`ast`: no cycle anywhere in
calibration/, drivers/, station/ and cli/, and the layers point one way.

Every ``import``/``from ... import`` counts, at module level and inside functions alike (a
function-level import hides a cycle from Python's loader, not from a reader). A module is a
node; ``from pkg import name`` is an edge to ``pkg.name`` when that is a module, otherwise to
``pkg``; importing ``a.b.c`` also runs ``a/__init__`` and ``a/b/__init__``, so it is an edge to
each of them too, except to the packages the importing module itself sits in (they ran before
it: that is containment, not a dependency)."""
import ast
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("calibration", "drivers", "station", "cli")


def module_files():
    """``{dotted module name: path}`` of every module in :data:`PACKAGES`."""
    found = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            found[".".join(parts)] = path
    return found


def _imported(node, name, is_package):
    """The dotted names a single ``import`` or ``from`` statement in module ``name`` asks for."""
    if isinstance(node, ast.Import):
        return [alias.name for alias in node.names]
    if node.level:          # relative: from its package upwards
        package = name.split(".") if is_package else name.split(".")[:-1]
        base = package[:len(package) - node.level + 1]
        stem = ".".join(base + ([node.module] if node.module else []))
    else:
        stem = node.module
    return [stem] + [f"{stem}.{alias.name}" for alias in node.names]


def import_graph():
    """``{module: {modules it imports}}`` over :data:`PACKAGES` (other imports left out)."""
    files = module_files()
    graph = {}
    for name, path in files.items():
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        is_package = path.name == "__init__.py"
        own = {".".join(name.split(".")[:i]) for i in range(1, name.count(".") + 1)}
        if is_package:
            own.add(name)
        edges = set()
        for node in ast.walk(tree):
            if not isinstance(node, (ast.Import, ast.ImportFrom)):
                continue
            asked = _imported(node, name, is_package)
            if isinstance(node, ast.ImportFrom):
                stem, names = asked[0], asked[1:]
                targets = [n for n in names if n in files] or [stem]
                if any(n not in files for n in names):
                    targets.append(stem)
            else:
                targets = asked
            for target in targets:
                parts = target.split(".")
                for i in range(1, len(parts) + 1):      # the packages it runs on the way
                    step = ".".join(parts[:i])
                    if step in files and step != name and (step not in own or step == target):
                        edges.add(step)
        graph[name] = edges
    return graph


def cycles(graph):
    """The strongly connected components of more than one module (Tarjan), each sorted,
    and one concrete loop through each: ``[(component, loop)]``."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []
    counter = [0]
    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10 * len(graph) + 100))

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return [(component, _loop(graph, component)) for component in found]


def _loop(graph, component):
    """A shortest loop from the component's first module back to it, inside the component."""
    inside = set(component)
    start = component[0]
    paths = {start: [start]}
    frontier = [start]
    while frontier:
        step = []
        for v in frontier:
            for w in sorted(graph[v] & inside):
                if w == start:
                    return paths[v] + [start]
                if w not in paths:
                    paths[w] = paths[v] + [w]
                    step.append(w)
        frontier = step
    return [start]


def describe(found):
    return "\n".join(f"{len(c)} modules: {' -> '.join(loop)}  (all: {', '.join(c)})"
                     for c, loop in found)


def room(module):
    """The room a module lives in: its package below ``station`` (``station.planning``), a
    module directly in station/ (``station.headless``), or its top-level package
    (``calibration``, ``drivers``, ``cli``, ``station`` for station/__init__)."""
    parts = module.split(".")
    if parts[0] == "station" and len(parts) >= 2:
        return ".".join(parts[:2])
    return parts[0]


def room_graph(graph):
    rooms = {}
    for module, targets in graph.items():
        here = room(module)
        rooms.setdefault(here, set())
        rooms[here] |= {room(t) for t in targets if room(t) != here}
    return rooms


def test_the_graph_sees_every_kind_of_import(tmp_path):
    """The reader itself: relative, function-level and ``from pkg import module`` imports are
    edges (a reader that missed one would pass any code)."""
    source = ("import os\n"
              "from . import sibling\n"
              "from .sub.deep import thing\n"
              "def f():\n"
              "    from station.batch import calibrate\n"
              "    import drivers.config\n")
    tree = ast.parse(source)
    asked = [n for node in ast.walk(tree) if isinstance(node, (ast.Import, ast.ImportFrom))
             for n in _imported(node, "station.planning.rounds", False)]
    assert "station.planning.sibling" in asked
    assert "station.planning.sub.deep.thing" in asked
    assert "station.batch.calibrate" in asked and "drivers.config" in asked
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert [c for c, _ in cycles(graph)] == [["a", "b", "c"]]
    assert cycles(graph)[0][1] == ["a", "b", "c", "a"]
    assert cycles({"a": {"b"}, "b": set()}) == []


def test_no_import_cycle():
    found = cycles(import_graph())
    assert not found, "import cycles:\n" + describe(found)


def test_no_cycle_between_rooms():
    """A room (a package under station/, or calibration/, drivers/) never reaches back into a
    room that imports it, even through different modules."""
    found = cycles(room_graph(import_graph()))
    assert not found, "cycles between rooms:\n" + describe(found)


# what each room may import besides itself: the layers point one way,
# the faces (gui, headless) -> simulation -> session -> planning -> fitting -> outputs
# -> recording -> calibration, drivers
_BELOW = ["calibration", "drivers", "station.recording", "station.outputs", "station.fitting",
          "station.planning", "station.session", "station.simulation"]
STATION_ROOMS = {room: set(_BELOW[:i]) for i, room in enumerate(_BELOW) if i >= 2}
STATION_ROOMS["station.doctor"] = {"calibration", "drivers", "station.outputs"}  # app.py doctor
STATION_ROOMS["station.headless"] = set(_BELOW)                        # app.py run
STATION_ROOMS["station.accuracy"] = set(_BELOW)                        # app.py accuracy
STATION_ROOMS["station.gui"] = set(_BELOW) | {"station.doctor"}        # the wizard
#: the command line (app.py's commands) sits on top of everything: any room of station/,
#: drivers and calibration; nothing imports it
CLI_ROOMS = {"station"} | set(STATION_ROOMS) | {"calibration", "drivers"}


def test_layers_point_one_way():
    """calibration imports neither drivers nor station; drivers never import station; each
    room of station/ imports only the rooms below it (:data:`STATION_ROOMS`); cli/ imports
    any of them (:data:`CLI_ROOMS`) and none of them imports cli/."""
    wrong = []
    for module, targets in sorted(import_graph().items()):
        here = room(module)
        for target in sorted(targets):
            there = room(target)
            if there == here or target == "station":
                continue
            if here == "calibration" or (here == "drivers" and there.startswith("station")):
                wrong.append(f"{module} -> {target}")
            elif there == "cli":
                wrong.append(f"{module} -> {target}")
            elif here in STATION_ROOMS and there not in STATION_ROOMS[here]:
                wrong.append(f"{module} -> {target}")
            elif here == "cli" and there not in CLI_ROOMS:
                wrong.append(f"{module} -> {target}")
    assert not wrong, "imports against the layers:\n" + "\n".join(wrong)


def test_station_modules_sit_in_rooms():
    """Every module of station/ lives in one of :data:`STATION_ROOMS`, so the layer test
    above covers all of them."""
    loose = [m for m in import_graph() if m.startswith("station.")
             and room(m) not in STATION_ROOMS]
    assert not loose, f"station/ modules outside a room: {loose}"


def test_the_command_line_is_a_package_of_its_own():
    """app.py is the entry point only: it imports cli/ (and the standard library), and
    cli/ is in the graph the tests above read."""
    tree = ast.parse((ROOT / "app.py").read_text(encoding="utf-8"))
    asked = {n.split(".")[0] for node in ast.walk(tree)
             if isinstance(node, (ast.Import, ast.ImportFrom))
             for n in _imported(node, "app", False)}
    assert asked & set(PACKAGES) == {"cli"}, asked
    graph = import_graph()
    assert {"cli", "cli.common", "cli.parser"} <= set(graph)
