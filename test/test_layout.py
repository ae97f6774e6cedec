# Copyright 2026 physdyn_ros maintainers
#
# Licensed under the Apache License, Version 2.0 (the "License");
# you may not use this file except in compliance with the License.
# You may obtain a copy of the License at
#
#     http://www.apache.org/licenses/LICENSE-2.0
#
# Unless required by applicable law or agreed to in writing, software
# distributed under the License is distributed on an "AS IS" BASIS,
# WITHOUT WARRANTIES OR CONDITIONS OF ANY KIND, either express or implied.
# See the License for the specific language governing permissions and
# limitations under the License.
"""The architecture holds: the learning core runs without ROS and without pybullet; the CLI answers."""
from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

from conftest import ROOT

CORE = ["physdyn_ros.conventions", "physdyn_ros.geometry", "physdyn_ros.data", "physdyn_ros.learn",
        "physdyn_ros.learn.model", "physdyn_ros.learn.train", "physdyn_ros.learn.evaluate",
        "physdyn_ros.predictor"]


def test_learning_core_imports_without_ros_and_pybullet():
    # A GPU training machine has neither: make both imports fail, then import every core module.
    code = textwrap.dedent(f"""
        import sys, importlib
        for blocked in ('rclpy', 'pybullet', 'pybullet_utils', 'rosbags'):
            sys.modules[blocked] = None
        for name in {CORE!r}:
            importlib.import_module(name)
        loaded = [m for m in ('rclpy', 'pybullet') if sys.modules.get(m) is not None]
        print('ok', loaded)
    """)
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert run.returncode == 0, run.stderr[-2000:]
    assert "ok []" in run.stdout


#: The ROS-free core: top-level packages / modules of physdyn_ros. The rest (ros, nodes and the
#: application modules cli, launcher, demo, info) may import anything below them.
CORE_PARTS = ("shapes", "sim", "data", "learn", "predictor", "planning", "bag", "perception", "geometry",
              "conventions", "resources")
#: Lazy imports the rules allow, each with its reason: (importing module, imported module prefix).
ALLOWED = {
    # the pybullet re-simulation baseline of `physdyn evaluate` (learn itself never imports pybullet)
    ("physdyn_ros.learn.baselines", "physdyn_ros.sim"),
}


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path) -> list[tuple[str, int]]:
    """Every module `path` imports, at module level or inside a function (lazy), absolute, with its line."""
    import ast

    name = _module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            out += [(a.name, node.lineno) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative: resolve against the importing package
                base = package.split(".")[:len(package.split(".")) - (node.level - 1)]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module or ""
            # `from . import geometry` imports a module too: count `module.name` as well as `module`
            out += [(module, node.lineno)] + [(f"{module}.{a.name}", node.lineno) for a in node.names]
    return out


def _violations(rules) -> list[str]:
    found = []
    for path in sorted((ROOT / "physdyn_ros").rglob("*.py")):
        src = _module_name(path)
        for imported, line in _imports(path):
            for applies, forbidden, why in rules:
                if not applies(src):
                    continue
                hit = next((f for f in forbidden if imported == f or imported.startswith(f + ".")), None)
                if hit and not any(src == a and imported.startswith(b) for a, b in ALLOWED):
                    found.append(f"{path.relative_to(ROOT)}:{line} imports {imported} ({why})")
    return found


def _in(*parts: str):
    prefixes = tuple(f"physdyn_ros.{p}" for p in parts)
    return lambda mod: any(mod == p or mod.startswith(p + ".") for p in prefixes)


LAYER_RULES = [
    (_in(*CORE_PARTS), ("rclpy", "physdyn_ros.ros", "physdyn_ros.nodes"),
     "the core runs without ROS and depends on no node"),
    (_in("learn"), ("pybullet", "pybullet_utils", "physdyn_ros.sim"), "learn runs on a machine without pybullet"),
    (_in("ros"), ("physdyn_ros.nodes",), "ros/ holds the adapters the nodes use: node -> ros -> core"),
]


def test_layers_hold_for_every_import_including_lazy_ones():
    """An AST scan of every module, function-level (lazy) imports included; the dependency goes nodes -> ros ->
    core, never back (a lazy import of a node from the core would pull rclpy into the ROS-free core)."""
    modules = list((ROOT / "physdyn_ros").rglob("*.py"))
    assert len(modules) > 50 and all(any(_in(p)(_module_name(m)) for m in modules) for p in CORE_PARTS)
    assert not _violations(LAYER_RULES), "\n".join(_violations(LAYER_RULES))


def test_every_core_module_imports_without_rclpy_and_the_ros_side():
    """The same rule at run time: with rclpy, physdyn_ros.ros and physdyn_ros.nodes unimportable, every core
    module (bag and planning included) imports."""
    names = sorted(_module_name(p) for p in (ROOT / "physdyn_ros").rglob("*.py") if _in(*CORE_PARTS)(_module_name(p)))
    code = textwrap.dedent(f"""
        import sys, importlib
        for blocked in ('rclpy', 'physdyn_ros.ros', 'physdyn_ros.nodes'):
            sys.modules[blocked] = None
        for name in {names!r}:
            importlib.import_module(name)
        print('ok', len({names!r}))
    """)
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=240)
    assert run.returncode == 0, run.stderr[-2000:]
    assert f"ok {len(names)}" in run.stdout


def test_layer_scan_sees_lazy_and_relative_imports(tmp_path, monkeypatch):
    """The scan itself: a lazy relative import of a node from a core module is caught."""
    import physdyn_ros  # noqa: F401

    fake_root = tmp_path
    pkg = fake_root / "physdyn_ros" / "bag"
    pkg.mkdir(parents=True)
    (fake_root / "physdyn_ros" / "__init__.py").write_text("")
    (pkg / "__init__.py").write_text("")
    (pkg / "x.py").write_text("def f():\n    from ..nodes.recorder_node import record\n    import rclpy\n")
    monkeypatch.setattr(sys.modules[__name__], "ROOT", fake_root)
    found = _violations(LAYER_RULES)
    assert any("x.py:2 imports physdyn_ros.nodes.recorder_node" in f for f in found), found
    assert any("x.py:3 imports rclpy" in f for f in found), found


def _import_graph() -> dict[str, dict[str, int]]:
    """Module -> {physdyn_ros module it imports: first line}, every import counted (lazy and TYPE_CHECKING ones
    too). An imported name resolves to the module it names: `from .planner import X` -> planner, `from . import
    geometry` -> geometry (not the package, whose __init__ merely runs first, as for any submodule)."""
    paths = sorted((ROOT / "physdyn_ros").rglob("*.py"))
    modules = {_module_name(p) for p in paths}

    def owner(name: str) -> str | None:  # the longest prefix of `name` that is a module of physdyn_ros
        parts = name.split(".")
        return next((m for m in (".".join(parts[:n]) for n in range(len(parts), 0, -1)) if m in modules), None)

    graph: dict[str, dict[str, int]] = {}
    for path in paths:
        src = _module_name(path)
        by_line: dict[int, list[str]] = {}
        for imported, line in _imports(path):
            by_line.setdefault(line, []).append(imported)
        edges = graph.setdefault(src, {})
        for line, names in sorted(by_line.items()):
            for name in names:
                # `from pkg import a, b` lists pkg, pkg.a, pkg.b: pkg counts only if a name is not a submodule
                subs = [n for n in names if n.startswith(name + ".")]
                if subs and all(n in modules for n in subs):
                    continue
                target = owner(name)
                if target is not None and target != src:
                    edges.setdefault(target, line)
    return graph


def _circles(graph: dict[str, dict[str, int]]) -> list[str]:
    """Every strongly connected group of modules (Tarjan), each shown as one cycle through it with its lines."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    groups: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in graph.get(v, {}):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                groups.append(sorted(group))

    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10000))
    for v in sorted(graph):
        if v not in index:
            visit(v)
    out = []
    for group in groups:
        members = set(group)
        path = [group[0]]  # walk inside the group back to its first module: one concrete cycle
        while True:
            nxt = sorted(w for w in graph[path[-1]] if w in members)
            back = [w for w in nxt if w == group[0]]
            step = back[0] if back and len(path) > 1 else next((w for w in nxt if w not in path), nxt[0])
            path.append(step)
            if step == group[0] or step in path[:-1]:
                break
        hops = " -> ".join(f"{a} (line {graph[a][b]})" for a, b in zip(path, path[1:])) + f" -> {path[-1]}"
        out.append(f"{len(group)} modules {group}: {hops}")
    return out


def test_no_import_circles_among_the_modules():
    """No module of physdyn_ros reaches itself through imports, lazy (function-level) ones included: a lazy
    import only hides a circle until the code path that runs it, and a circle means neither module can be read,
    tested or moved on its own."""
    circles = _circles(_import_graph())
    assert not circles, "import circles:\n" + "\n".join(circles)


def test_circle_scan_sees_lazy_and_relative_imports(tmp_path, monkeypatch):
    """The scan itself: a lazy relative import that closes a loop is a circle; a package __init__ importing its
    submodules, and a submodule importing a sibling through `from . import x`, are not."""
    pkg = tmp_path / "physdyn_ros" / "p"
    pkg.mkdir(parents=True)
    (tmp_path / "physdyn_ros" / "__init__.py").write_text("")
    (pkg / "__init__.py").write_text("from .a import f\nfrom .b import g\n")
    (pkg / "a.py").write_text("from . import c\n\ndef f():\n    from .b import g\n")
    (pkg / "b.py").write_text("from .c import h\n")
    (pkg / "c.py").write_text("def h():\n    from physdyn_ros.p.a import f\n")
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    circles = _circles(_import_graph())
    assert len(circles) == 1 and "['physdyn_ros.p.a', 'physdyn_ros.p.b', 'physdyn_ros.p.c']" in circles[0], circles
    (pkg / "c.py").write_text("def h():\n    pass\n")
    assert not _circles(_import_graph())


def test_cli_lists_commands_and_rejects_unknown_ones():
    exe = ROOT / ".venv" / "bin" / "physdyn"
    ok = subprocess.run([str(exe), "--help"], capture_output=True, text=True, timeout=60)
    assert ok.returncode == 0
    for command in ("generate", "train", "evaluate", "up", "demo"):
        assert command in ok.stdout
    bad = subprocess.run([str(exe), "no-such-command"], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "invalid choice" in bad.stderr


def test_info_reports_interfaces():
    exe = ROOT / ".venv" / "bin" / "physdyn"
    run = subprocess.run([str(exe), "info", "--json"], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    import json
    info = json.loads(run.stdout[run.stdout.index("{"):])
    assert {"ObjectState", "PredictedTrajectory", "ShapeFeature", "PredictTrajectory", "PushObject"} <= set(
        info["interfaces"])


def test_package_xml_lists_every_ros_package_the_code_imports():
    """Every ROS package the code imports is declared in package.xml (rosdep and colcon read it, not the
    code)."""
    import ast
    import xml.etree.ElementTree as ET

    root = ROOT
    declared = {e.text for e in ET.parse(root / "package.xml").getroot()
                if e.tag.endswith("depend") and e.text}
    ros_like = ("rclpy", "launch", "launch_ros", "ament_index_python", "tf2_ros", "tf2_msgs", "lifecycle_msgs")
    imported = set()
    for path in [*(root / "physdyn_ros").rglob("*.py"), *(root / "launch").glob("*.py")]:
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module] if isinstance(node, ast.ImportFrom) and node.module and node.level == 0 else []
            for name in names:
                top = name.split(".")[0]
                if top.endswith(("_msgs", "_srvs", "_interfaces")) or top in ros_like:
                    imported.add(top)
    assert imported, "no ROS imports found: the scan is broken"
    missing = sorted(imported - declared)
    assert not missing, f"package.xml lacks <depend>/<exec_depend> for {missing}"


def test_requirements_pin_what_the_code_imports():
    """requirements.txt pins every third-party import, and nothing that is never imported."""
    import ast
    import importlib.metadata as md
    import re
    import sys

    pinned = {re.split(r"[=<>\[ ]", ln.strip(), maxsplit=1)[0].lower().replace("_", "-")
              for ln in (ROOT / "requirements.txt").read_text().splitlines() if ln.strip() and ln[0] != "#"}
    owners = md.packages_distributions()
    ours = {"physdyn_ros", "conftest", "learn_support", "test_nodes_support", "test_bag_support"}
    imported: dict[str, str] = {}
    for path in [*(ROOT / "physdyn_ros").rglob("*.py"), *(ROOT / "test").glob("*.py"), *(ROOT / "bench").glob("*.py")]:
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module] if isinstance(node, ast.ImportFrom) and node.module and node.level == 0 else []
            for name in names:
                top = name.split(".")[0]
                if top not in sys.stdlib_module_names and top not in ours and not top.startswith("test_"):
                    imported.setdefault(top, str(path.relative_to(ROOT)))
    unpinned = []
    for top, where in sorted(imported.items()):
        dists = {d.lower().replace("_", "-") for d in owners.get(top, [])}
        if not dists:
            continue  # a module of the ROS wheels or of the generated interfaces
        if not dists & pinned and not any(d.startswith("ros-") for d in dists):
            unpinned.append(f"{top} ({', '.join(sorted(dists))}, imported by {where})")
    assert not unpinned, f"requirements.txt does not pin: {unpinned}"
    used = {d.lower().replace("_", "-") for t in imported for d in owners.get(t, [])}
    tools = ("ros-", "colcon-", "catkin-pkg", "pytest", "ruff", "mypy")  # build, test, lint tools: run, not imported
    unused = sorted(d for d in pinned if not d.startswith(tools) and d not in used)
    assert not unused, f"pinned but never imported: {unused}"


def test_ruff_is_clean():
    """pyflakes and pycodestyle (ruff.toml) over the package, benches and tests."""
    ruff = Path(sys.executable).parent / "ruff"
    run = subprocess.run([str(ruff), "check", "--output-format", "concise", "."], cwd=ROOT, capture_output=True,
                         text=True, timeout=120)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-1000:]


def test_mypy_is_clean_on_the_core():
    """mypy (pinned; mypy.ini) over the ROS-free core, every core folder of the layering rules."""
    import configparser

    cfg = configparser.ConfigParser()
    cfg.read(ROOT / "mypy.ini")
    files = {f.strip().rstrip(",") for f in cfg["mypy"]["files"].split()}
    listed = {Path(f).with_suffix("").name if f.endswith(".py") else Path(f).name for f in files}
    assert listed == set(CORE_PARTS), f"mypy.ini checks {sorted(listed)}, the core is {sorted(CORE_PARTS)}"
    mypy = Path(sys.executable).parent / "mypy"
    run = subprocess.run([str(mypy)], cwd=ROOT, capture_output=True, text=True, timeout=280)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-1000:]
