"""Which paths SUMO and the file system can take as output folders: the checks behind every --out and
--nets-dir, each returning why not as a phrase to follow the flag."""

from __future__ import annotations

import locale
import os
import sys
import tempfile
from pathlib import Path

NAME_ROOM = 18
"""bytes a run adds to the last name of --out: its partial folder '.<name>.partial-XXXXXXXX' beside it"""
PATH_ROOM = 256
"""bytes left free under PATH_MAX for the files a command writes inside --out (the deepest: a study's run folders)"""


def _exists(path: Path) -> bool:
    """Path.exists, False where the system cannot even look (a name too long, a loop, no permission)."""
    try:
        return path.exists()
    except OSError:
        return False


def nearest_existing(path: Path) -> Path:
    """`path` or its nearest ancestor that exists."""
    folder = path
    while not _exists(folder) and folder != folder.parent:
        folder = folder.parent
    return folder


def _fs_limits(path: Path) -> tuple[int, int]:
    """(NAME_MAX, PATH_MAX) in bytes of the file system holding path's nearest existing folder."""
    folder = nearest_existing(path)
    try:
        return os.pathconf(folder, "PC_NAME_MAX"), os.pathconf(folder, "PC_PATH_MAX")
    except (OSError, ValueError):
        return 255, 4096


def _utf8_locale() -> bool:
    """True when the C library's character set is UTF-8 (SUMO opens files by names in it; LC_ALL=C is ASCII)."""
    return locale.nl_langinfo(locale.CODESET).replace("-", "").lower() == "utf8"


def utf8_problem(text: str) -> str | None:
    """Why `text` (a path or an argument) cannot be taken, or None: a byte that is not valid UTF-8 (Python holds it as
    a lone surrogate, '\\udcff'), which SUMO cannot take as a file name and coopsumo cannot write into its own files
    (issue 82, probe 7, I9: a traceback, a partial folder left behind)."""
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        return f"{text!r} has a byte that is not valid UTF-8, which SUMO and coopsumo's records cannot take; rename it"
    return None


def _dangling(absolute: Path) -> Path | None:
    """`absolute` when it is itself a symbolic link leading nowhere, else None: the output folder would be made at the
    link's target by some writers and refused as existing by others (issue 82, probe 7, I17d: `train --out lnk` said
    "File exists" after 6 s). A link to a folder yet to be made above the output folder is fine: the path is written
    resolved."""
    return absolute if os.path.islink(absolute) and not _exists(absolute) else None


def _target(link: Path) -> str:
    try:
        return os.readlink(link)
    except OSError:
        return "?"


def out_path_problem(path: Path) -> str | None:
    """Why SUMO or the file system cannot take `path` as an output folder (a phrase to follow the flag), or None.

    Refused: a relative path starting with '~' (SUMO would expand it to a home folder and write there; issue 82,
    probe 9: `train --out '~/exp'` overwrote $HOME/exp's SUMO files); a relative path when the current folder was
    deleted; ':' (SUMO reads it as host:port), ',' (SUMO splits its file lists at commas) or '${' (SUMO substitutes
    environment variables in its file names: probe 9) anywhere in the absolute path; non-ASCII characters under an
    ASCII locale (LC_ALL=C: SUMO cannot open such names); a byte that is not valid UTF-8 (utf8_problem); a
    symbolic link loop; the path itself a link leading nowhere; a file where a folder must be;
    a name longer than NAME_MAX less NAME_ROOM, a path longer than PATH_MAX less PATH_ROOM.
    """
    if not path.is_absolute() and path.parts and path.parts[0].startswith("~"):
        return (f"{str(path)!r} starts with '~', which SUMO reads as a home folder while coopsumo does not (the "
                "shell expands only an unquoted ~): give the folder as $HOME/... or an absolute path")  # fmt: skip
    try:
        absolute = path.absolute()
    except OSError:  # os.getcwd(): the current folder is gone
        return (f"{str(path)!r} is relative, but the current folder no longer exists (deleted?); change to an "
                "existing folder or give an absolute path")  # fmt: skip
    text = str(absolute)
    try:
        real = absolute.resolve()
    except (RuntimeError, OSError):  # Python 3.11: RuntimeError for a loop; later versions: OSError ELOOP
        return f"{text!r} goes through a loop of symbolic links"
    for shown in dict.fromkeys((text, str(real))):
        if problem := utf8_problem(shown):
            return problem
        if ":" in shown:
            return (f"must be a folder path without ':' (SUMO reads an output file name with ':' as host:port), "
                    f"got {shown!r}")  # fmt: skip
        if "," in shown:
            return f"must be a folder path without ',' (SUMO splits its lists of files at commas), got {shown!r}"
        if "${" in shown:  # issue 82, probe 9: 'd${XV}' made SUMO write into dzz, another training's folder
            return (f"must be a folder path without '${{' (SUMO reads ${{NAME}} in a file name as an environment "
                    f"variable), got {shown!r}")  # fmt: skip
        if not shown.isascii() and not _utf8_locale():
            return (f"{shown!r} has non-ASCII characters, which SUMO cannot open under this ASCII locale "
                    f"({locale.setlocale(locale.LC_CTYPE)}); set LC_ALL=C.UTF-8 or pick an ASCII path")  # fmt: skip
    if link := _dangling(absolute):
        return f"{str(link)!r} is a link that leads nowhere (to {_target(link)!r}); remove it or pick another path"
    if problem := length_problem(real, "the run's partial folder"):
        return problem
    folder = nearest_existing(real)
    if folder != real and not folder.is_dir():
        return f"output folder {text!r} cannot be made: {folder} is a file, not a folder"
    return None


def length_problem(real: Path, beside: str) -> str | None:
    """Why the file system cannot take the absolute path `real` with room for what is written beside its last name
    (`beside`, in words) and inside it, or None: a name longer than NAME_MAX (its last less NAME_ROOM), the path
    longer than PATH_MAX less PATH_ROOM."""
    name_max, path_max = _fs_limits(real)
    for part in real.parts[1:]:
        if len(os.fsencode(part)) > name_max - (NAME_ROOM if part == real.name else 0):
            limit = name_max - NAME_ROOM if part == real.name else name_max
            return (f"has a name of {len(os.fsencode(part))} bytes ({part[:20]}...); at most {limit} are allowed "
                    f"here (the file system's {name_max}, less room for {beside})")  # fmt: skip
    if len(os.fsencode(str(real))) > path_max - PATH_ROOM:
        return (f"is {len(os.fsencode(str(real)))} bytes long; at most {path_max - PATH_ROOM} are allowed (the file "
                f"system's {path_max}, less room for the files written inside)")  # fmt: skip
    return None


def nets_dir_problem(text: str) -> str | None:
    """Why `text` cannot be the networks folder (a phrase to follow --nets-dir or $COOPSUMO_NETS_DIR), or None:
    empty, a path SUMO or the file system cannot take (out_path_problem), a file, or a folder not writable."""
    if not text.strip():
        return "must name a folder, got an empty string"
    path = Path(text).expanduser()
    if problem := out_path_problem(path):
        return problem.replace("folder path", "path")
    real = path.resolve()
    if _exists(real) and not real.is_dir():
        return f"{text!r} is a file, not a folder"
    folder = nearest_existing(real)
    if not os.access(folder, os.W_OK | os.X_OK) or not _can_make_a_file_in(folder):
        return f"{text!r} cannot be written: {folder} is not writable"
    return None


def _can_make_a_file_in(folder: Path) -> bool:
    """True when a file can be made in `folder`: os.access says yes to root everywhere, /proc and /sys included. The
    test file has no name where the system allows (O_TMPFILE) and is gone at once."""
    try:
        with tempfile.TemporaryFile(dir=folder):
            return True
    except OSError:
        return False


def outside_link(folder: Path) -> tuple[Path, Path] | None:
    """The first symbolic link under `folder` (none followed) that leads outside it, and where it leads; None when
    there is none. A command writing into `folder` would write through such a link into a folder it does not own."""
    root = folder.resolve()
    for parent, folders, files in os.walk(root):
        for name in folders + files:
            path = Path(parent) / name
            if path.is_symlink() and not (target := path.resolve()).is_relative_to(root):
                return path, target
    return None


NETS_ENV = "COOPSUMO_NETS_DIR"
"""environment variable naming the folder the SUMO networks are built into (read by sim.network)"""
STORE_ENV = "COOPSUMO_MODELS"
"""environment variable naming the studies' model store (studies/engine/model_store.py; unset or empty:
results/models)"""


def nets_in_out_problem(out: Path) -> str | None:
    """Why `out` may not be written while $COOPSUMO_NETS_DIR (its links resolved) is `out` or lies in it (a phrase to
    follow the flag, run_dirs.check_out_path), or None: the networks SUMO builds there would be taken for the command's
    own files (as `coopsumo --nets-dir D COMMAND --out D` is refused)."""
    nets = os.environ.get(NETS_ENV)
    if not nets:
        return None
    try:
        real, target = Path(nets).expanduser().resolve(), out.resolve()
    except (RuntimeError, OSError):  # a loop of links: out_path_problem and env_problem name it
        return None
    if not real.is_relative_to(target):
        return None
    return (f"{out} {'is' if real == target else 'holds'} the networks folder ${NETS_ENV} {nets}: the networks SUMO "
            "builds would fill the output folder; pick a networks folder outside it")  # fmt: skip


def policy_path_problem(path: Path, models: str = "the models trained here") -> str | None:
    """Why a policy string (dqn:PATH, policy_spec.parse_policy) could not name a model under `path`, or None: a space
    (any whitespace) in it as given, absolute or with its links resolved. ',' and ':' are out_path_problem's.
    models: which models the policy string names, in the line."""
    try:
        shown = (str(path), str(path.absolute()), str(path.resolve()))
    except (RuntimeError, OSError):
        return None  # out_path_problem names a loop or a deleted current folder
    bad = next((text for text in dict.fromkeys(shown) if any(ch.isspace() for ch in text)), None)
    if bad is None:
        return None
    return (f"must be a folder path without spaces: a policy string (dqn:PATH) names {models} and cannot "
            f"hold a space, got {bad!r}")  # fmt: skip


def env_problem() -> str | None:
    """Why a folder the environment names cannot be used ('$NAME ...', a line to follow 'error: '), or None: every
    variable the package reads a folder from, checked like --nets-dir (nets_dir_problem) before a command starts, and
    $TMPDIR by the path rules SUMO needs (out_path_problem) and a policy string's (policy_path_problem)."""
    for name, may_be_empty in ((NETS_ENV, False), (STORE_ENV, True)):
        value = os.environ.get(name)
        if value is None or (may_be_empty and not value):
            continue
        # coopsumo takes the store's path as given, so a '~' there is SUMO's alone (issue 82, probe 10, L1: SUMO
        # wrote into $HOME/m's model); the networks folder is expanded (nets_dir_problem)
        if problem := (out_path_problem(Path(value)) if name == STORE_ENV else None) or nets_dir_problem(value):
            return f"${name} {problem.replace('folder path', 'path')}"
    # SUMO writes bench's and the screenshot's runs there (issue 82, probe 10, L5: ',', ':' and '${' were tracebacks),
    # and bench's policy strings name the models it trains there (probe 12, N10: a space failed after its trainings)
    tmp = Path(value) if (value := os.environ.get("TMPDIR")) else None
    models = "the models bench trains there"
    if tmp is not None and (problem := out_path_problem(tmp) or policy_path_problem(tmp, models)):
        return f"$TMPDIR {problem.replace('folder path', 'path')}"
    return None


def library_env_problem() -> str | None:
    """Why a variable that matplotlib or tqdm reads when imported stops its import (a line naming it), or None:
    $MPLBACKEND not a backend matplotlib knows (coopsumo draws its figures on matplotlib's Agg canvas and needs none;
    judged by matplotlib with the variable put aside while it is imported, then put back), a $TQDM_* value tqdm cannot
    convert (its progress bars' settings). Issue 82, probe 17: `MPLBACKEND=bogus` or `TQDM_MININTERVAL=abc` ended
    commands in a ValueError traceback. Judged only when such a variable is set and its library not yet imported."""
    backend = os.environ.get("MPLBACKEND")
    if backend and "matplotlib" not in sys.modules:
        del os.environ["MPLBACKEND"]
        try:
            from matplotlib.rcsetup import validate_backend

            validate_backend(backend)
        except ValueError:
            return (f"$MPLBACKEND {backend!r} is not a backend matplotlib knows (coopsumo draws its figures into files "
                    "and needs none): unset it or name one, e.g. agg")  # fmt: skip
        finally:
            os.environ["MPLBACKEND"] = backend
    names = sorted(name for name in os.environ if name.startswith("TQDM_"))
    if names and "tqdm" not in sys.modules:
        try:
            import tqdm  # noqa: F401 (its import converts every $TQDM_* value)
        except (ValueError, TypeError) as err:
            shown = ", ".join(f"${name}={os.environ[name]!r}" for name in names)
            why = str(err).splitlines()[0] if str(err) else type(err).__name__
            return (f"{shown}: a value the progress bars' library (tqdm) cannot take ({why}); unset it or "
                    "give one it takes")  # fmt: skip
    return None
