"""Run SUMO's ``netconvert`` (from the ``eclipse-sumo`` wheel, extra ``cmudrive[maps]``).

netconvert is only needed to *build* networks (procedural towns, OpenDRIVE / OpenStreetMap import);
running the benchmark reads the committed ``.net.xml`` files with sumolib and never needs it.
Outputs are written to a temporary file next to the target and moved into place only on success, so a
failed conversion never leaves a half-written network behind.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path

from cmudrive.maps.errors import NetconvertError

INSTALL_HINT = "install it with: pip install 'cmudrive[maps]' (the eclipse-sumo wheel ships netconvert)"


def find_netconvert() -> Path:
    """Locate the netconvert binary: ``$SUMO_HOME/bin``, the ``eclipse-sumo`` wheel, then ``PATH``."""
    candidates: list[Path] = []
    if os.environ.get("SUMO_HOME"):
        candidates.append(Path(os.environ["SUMO_HOME"]) / "bin" / "netconvert")
    try:
        import sumo  # the eclipse-sumo wheel

        candidates.append(Path(sumo.SUMO_HOME) / "bin" / "netconvert")
    except ImportError:
        pass
    on_path = shutil.which("netconvert")
    if on_path:
        candidates.append(Path(on_path))
    for path in candidates:
        if path.is_file() and os.access(path, os.X_OK):
            return path
    raise NetconvertError(f"netconvert not found; {INSTALL_HINT}")


def run_netconvert(args: Sequence[str], output: Path, *, source: str, timeout_s: float = 600.0) -> Path:
    """Run ``netconvert ARGS -o <tmp>`` and atomically move the result to ``output``.

    ``source`` names the input (file or town) in error messages. Returns ``output``.
    """
    binary = find_netconvert()
    output = Path(output)
    output.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(prefix=f".{output.name}.", suffix=".tmp.net.xml", dir=output.parent)
    os.close(fd)
    tmp = Path(tmp_name)
    cmd = [str(binary), *args, "--output-file", str(tmp)]
    try:
        try:
            proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s, check=False)
        except subprocess.TimeoutExpired as exc:
            raise NetconvertError(f"netconvert timed out after {timeout_s:.0f} s on {source}") from exc
        if proc.returncode != 0 or not tmp.exists() or tmp.stat().st_size == 0:
            tail = "\n".join((proc.stderr or proc.stdout).strip().splitlines()[-15:])
            raise NetconvertError(f"netconvert failed on {source} (exit {proc.returncode}):\n{tail}")
        umask = os.umask(0)
        os.umask(umask)
        tmp.chmod(0o666 & ~umask)  # mkstemp's 0600 would make the network unreadable to other users
        os.replace(tmp, output)
    finally:
        if tmp.exists():
            tmp.unlink()
    return output


_HEADER = re.compile(r"<!-- generated on .*? by (?P<tool>Eclipse SUMO netconvert [^\n]*?)\n.*?-->\n", re.S)


def write_with_fixed_header(built: Path, path: Path, describe: Callable[[str], str], source: str) -> None:
    """Copy the network ``built`` to ``path`` (atomically, mode 0644) with netconvert's header comment
    (build time, temporary input paths) replaced by ``describe(tool)``, ``tool`` being netconvert's name and
    version: the same inputs and netconvert version then give a byte-identical file."""
    text = built.read_text(encoding="utf-8")
    m = _HEADER.search(text, 0, 20000)
    if m is None:
        raise NetconvertError(f"{source}: unexpected netconvert header in {built}")
    body = describe(m.group("tool")).replace("--", "-")  # "--" may not appear inside an XML comment
    text = text[: m.start()] + f"<!-- {body} -->\n" + text[m.end() :]
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8", newline="\n") as fh:
            fh.write(text)
        os.chmod(tmp, 0o644)  # a plain data file (mkstemp makes it private)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
