"""SUMO network and detector files: the straight highway built by netconvert, E1 loops every 200 m.

Pure file generation plus one call of SUMO's `netconvert` binary; no libsumo here. Where the networks go
(nets_dir): the folder COOPSUMO_NETS_DIR names (`coopsumo --nets-dir DIR` sets it), else the checkout's
top-level sumo_nets/ when running from a source checkout, else the per-user cache
$XDG_CACHE_HOME/coopsumo/sumo_nets (~/.cache/coopsumo/sumo_nets). Nothing is written inside the package.
"""

from __future__ import annotations

import errno
import os
import re
import subprocess
import sys
import tempfile
from collections.abc import Mapping
from pathlib import Path

from coopsumo.config import RoadConfig
from coopsumo.files import read_text
from coopsumo.paths import NETS_ENV

EDGE_ID = "road"
ROUTE_ID = "r0"
VTYPE_ID = "car"
SOURCE_ROOT = Path(__file__).resolve().parents[2]
"""the folder holding the package: a source checkout's root, or site-packages' parent for an installed wheel"""


def checkout_root() -> Path | None:
    """The source checkout this package runs from (its pyproject.toml names coopsumo), or None when installed."""
    try:
        text = (SOURCE_ROOT / "pyproject.toml").read_text()
    except OSError:
        return None
    return SOURCE_ROOT if 'name = "coopsumo"' in text else None


def nets_dir(environ: Mapping[str, str] | None = None) -> Path:
    """The folder networks are built into (see the module's docstring for the order)."""
    env = os.environ if environ is None else environ
    if env.get(NETS_ENV):
        return Path(env[NETS_ENV]).expanduser()
    root = checkout_root()
    if root is not None:
        return root / "sumo_nets"
    cache = Path(env["XDG_CACHE_HOME"]) if env.get("XDG_CACHE_HOME") else Path.home() / ".cache"
    return cache / "coopsumo" / "sumo_nets"


def netconvert_binary() -> str:
    """Path of the netconvert binary shipped by the eclipse-sumo wheel."""
    import sumo  # the eclipse-sumo wheel; only its path is used

    path = Path(sumo.SUMO_HOME) / "bin" / "netconvert"
    if not path.exists():
        raise FileNotFoundError(f"netconvert not found at {path}; install eclipse-sumo")
    return str(path)


def net_name(road: RoadConfig) -> str:
    """File stem of the network for this road (lanes, length, width, speed limit)."""
    return f"highway_{road.lanes}lanes_{road.length_m:g}m_w{road.lane_width_m:g}_v{road.speed_limit_mps:g}"


def plain_xml(road: RoadConfig) -> tuple[str, str]:
    """The node and edge files of SUMO's plain XML format for the road."""
    nodes = (
        "<nodes>\n"
        '    <node id="upstream" x="0.00" y="0.00" type="priority"/>\n'
        f'    <node id="downstream" x="{road.length_m:.2f}" y="0.00" type="priority"/>\n'
        "</nodes>\n"
    )
    edges = (
        "<edges>\n"
        f'    <edge id="{EDGE_ID}" from="upstream" to="downstream" numLanes="{road.lanes}" '
        f'speed="{road.speed_limit_mps:.2f}" width="{road.lane_width_m:.2f}" spreadType="center"/>\n'
        "</edges>\n"
    )
    return nodes, edges


def build_net(road: RoadConfig, folder: Path | None = None) -> Path:
    """Build (once) the network for this road with netconvert into folder (default: nets_dir()); returns the
    .net.xml path. Written atomically, so parallel runs asking for the same network do not clash.
    """
    folder = folder if folder is not None else nets_dir()
    folder.mkdir(parents=True, exist_ok=True)
    stem = net_name(road)
    net_path = folder / f"{stem}.net.xml"
    if net_path.is_dir():
        raise IsADirectoryError(errno.EISDIR, "the network file is a folder (move it away to build the network)",
                                str(net_path))  # fmt: skip
    if net_path.exists():
        problem = net_problem(net_path, road)
        if problem is None:
            return net_path
        print(f"network {net_path} is damaged ({problem}): building it again", file=sys.stderr)
    nodes, edges = plain_xml(road)
    _write_own(folder / f"{stem}.nod.xml", nodes)
    _write_own(folder / f"{stem}.edg.xml", edges)
    fd, tmp = tempfile.mkstemp(suffix=".net.xml", dir=folder)
    os.close(fd)
    cmd = [
        netconvert_binary(),
        "--node-files", str(folder / f"{stem}.nod.xml"),
        "--edge-files", str(folder / f"{stem}.edg.xml"),
        "--output-file", tmp,
        "--no-turnarounds", "true",
        "--no-warnings", "true",
    ]  # fmt: skip
    try:
        result = subprocess.run(cmd, capture_output=True, text=True, check=False)
        text = read_text(Path(tmp), errors="replace") if result.returncode == 0 else ""
        if result.returncode != 0:
            said = (result.stderr.strip().splitlines() or [f"exit code {result.returncode}"])[-1]
        elif problem := _content_problem(text, road):
            said = f"its network is {problem}"
        if result.returncode != 0 or problem:  # a full networks folder, a file-size limit (probe 19, TB1: a traceback)
            raise OSError(errno.EIO, f"netconvert could not build the network ({said}; is the networks folder full, "
                          "or a file-size limit set?)", str(net_path))  # fmt: skip
        Path(tmp).write_text(text + f"{SEAL_OPEN}{_digest(text)}{SEAL_CLOSE}\n")
        os.replace(tmp, net_path)
    finally:
        Path(tmp).unlink(missing_ok=True)  # gone after os.replace; left by a failure otherwise
    return net_path


def _write_own(path: Path, text: str) -> None:
    """Write `text` as the file `path` of the networks folder: a new file renamed over the name, so a link there (to a
    user's file) is replaced, never written through; its temporary file is removed if that fails."""
    fd, tmp = tempfile.mkstemp(suffix=".xml.tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w") as handle:
            handle.write(text)
        os.replace(tmp, path)
    finally:
        Path(tmp).unlink(missing_ok=True)  # gone after os.replace; left by a failure otherwise


SEAL_OPEN, SEAL_CLOSE = "<!-- coopsumo sha256 ", " -->"
"""the comment build_net ends a network it built with: the sha256 of its network (from `<net ` on; netconvert's
header before it carries the time it ran), so that a cached network edited since is built again (issue 82, probe 18:
lanes that forbid cars or lane changes were driven, a traceback or other results without a line)"""
_SEAL = re.compile(rf"{re.escape(SEAL_OPEN)}([0-9a-f]{{64}}){re.escape(SEAL_CLOSE)}\s*\Z")


def _digest(text: str) -> str:
    import hashlib

    start = text.find("<net ")
    return hashlib.sha256(text[max(start, 0):].encode("utf-8", "surrogateescape")).hexdigest()


def net_problem(path: Path, road: RoadConfig) -> str | None:
    """Why the cached network file at `path` is not the whole network of `road` that build_net built (empty, cut
    short, garbage, another number of lanes, lanes of another length, speed limit or width; then anything edited since
    it was built: its seal), or None. A cheap look: the file is a few kB, written atomically by build_net."""
    try:
        text = read_text(path, errors="replace")  # a named pipe is refused, not waited on
    except OSError as err:
        return f"unreadable: {err.strerror}"
    seal = _SEAL.search(text)
    content = text if seal is None else text[: seal.start()]
    if problem := _content_problem(content, road):
        return problem
    if seal is None:
        return "it carries no seal of coopsumo's build (built by an older coopsumo, or edited)"
    if seal.group(1) != _digest(content):
        return "it is not the network netconvert wrote for it (edited since it was built?)"
    return None


def _content_problem(text: str, road: RoadConfig) -> str | None:
    """Why the network `text` is not a whole network of `road` (net_problem's look at its lanes), or None."""
    if not text.rstrip().endswith("</net>"):
        return "empty or cut short" if len(text.strip()) < 20 or "<net" in text else "not a SUMO network"
    lanes = re.findall(rf'<lane id="{EDGE_ID}_(\d+)"([^>]*)>', text)
    if sorted(int(index) for index, _ in lanes) != list(range(road.lanes)):
        return f"lanes {', '.join(index for index, _ in lanes) or 'none'} instead of 0-{road.lanes - 1}"
    wanted = {"length": road.length_m, "speed": road.speed_limit_mps, "width": road.lane_width_m}
    for index, attributes in lanes:
        for name, value in wanted.items():
            found = re.search(rf' {name}="([^"]*)"', attributes)
            if found is None or not _within_rounding(found.group(1), value):
                return f"lane {index} has {name} {found.group(1) if found else 'none'} instead of {value:.2f}"
    return None


def _within_rounding(text: str, value: float) -> bool:
    """True when `text` is a number within the rounding of netconvert's two decimals of `value`."""
    try:
        return abs(float(text) - value) <= 0.006
    except ValueError:
        return False


def loop_id(pos_m: float, lane: int) -> str:
    """Detector id, e.g. e1_x1200_l2 (position in m, SUMO lane index)."""
    return f"e1_x{int(round(pos_m)):05d}_l{lane}"


def detectors_xml(road: RoadConfig, output_file: str) -> str:
    """An additional file with one E1 induction loop per lane every loop_spacing_m."""
    lines = ["<additional>"]
    for pos in road.loop_positions_m():
        for lane in range(road.lanes):
            lines.append(
                f'    <inductionLoop id="{loop_id(pos, lane)}" lane="{EDGE_ID}_{lane}" pos="{pos:.2f}" '
                f'period="{road.loop_period_s:g}" file="{output_file}"/>'
            )
    lines.append("</additional>")
    return "\n".join(lines) + "\n"


def routes_xml(max_speed_mps: float, car_length_m: float, lc_motivations: bool = True) -> str:
    """The route file: one route over the road and the vehicle type (SUMO's models only for `sumo`).

    lc_motivations=False (controlled runs, lane-change mode 0) switches off LC2013's reasons to change lane
    (strategic, cooperative, speed gain, keep right): SUMO's lane changer still looks at every vehicle every
    step, a little faster; outputs are byte-identical (docs/model.md, "Deviations and choices")."""
    lc = "" if lc_motivations else ' lcStrategic="-1" lcCooperative="0" lcSpeedGain="0" lcKeepRight="0"'
    return (
        "<routes>\n"
        f'    <vType id="{VTYPE_ID}" length="{car_length_m:g}" minGap="2.5" maxSpeed="{max_speed_mps:.2f}" '
        f'accel="2.6" decel="4.5" emergencyDecel="9.0" sigma="0.5" speedFactor="1" speedDev="0"{lc}/>\n'
        f'    <route id="{ROUTE_ID}" edges="{EDGE_ID}"/>\n'
        "</routes>\n"
    )


def net_file_refusal(path: str) -> str:
    """Why the world does not drive the SUMO network file at `path` (a phrase to follow the flag): it builds its own
    straight highway from RoadConfig and reads positions along that one edge, so a network file is never driven. A
    file that is one straight edge of 2-6 lanes is answered with the flags that build the same road."""
    import math

    import sumolib

    from coopsumo.files import not_regular

    if kind := not_regular(Path(path)):  # sumolib would wait on a named pipe for ever (issue 82, probe 18, O1)
        return f"{path} is not a regular file but {kind}"
    if not Path(path).exists():  # sumolib calls it no network (probe 20, O2)
        return f"no such file: {path}"
    try:
        net = sumolib.net.readNet(path)
    except Exception as err:  # sumolib raises many types (a missing file, XML errors) for a file it cannot read
        return f"{path} is not a SUMO network sumolib can read ({type(err).__name__})"
    edges = net.getEdges(withInternal=False)
    needs = ("the world drives its own road only: one straight edge of 2-6 parallel lanes, built by netconvert from "
             "--lanes, --road-length and --speed-limit (positions along that edge, its lanes each vehicle's left, "
             "own and right, loops on every lane every --loop-spacing)")  # fmt: skip
    if len(edges) != 1:
        return f"{path} has {len(edges)} edges; {needs}"
    edge = edges[0]
    (x0, y0), (x1, y1) = edge.getShape()[0][:2], edge.getShape()[-1][:2]
    chord = math.hypot(x1 - x0, y1 - y0)
    lanes, length, speed = edge.getLaneNumber(), edge.getLength(), edge.getSpeed()
    if abs(chord - length) > 0.01 * length or not 2 <= lanes <= 6:
        return f"{path}'s edge {edge.getID()} is not straight or has {lanes} lanes; {needs}"
    return (f"{needs}; {path} is such a road: give it as --lanes {lanes} --road-length {length:g} --speed-limit "
            f"{speed:g}")
