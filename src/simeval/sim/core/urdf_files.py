"""URDFs written at run time (procedural objects, fixtures, the arms drawn with their collision meshes): one file
per distinct text in the temp folder, named by its hash, written atomically so parallel workers never read half a
file and every process after the first reuses it."""

from __future__ import annotations

import hashlib
import os
import tempfile


def write_temp_urdf(text: str, kind: str) -> str:
    """The path of a URDF holding `text` (`kind` names it: simeval-<kind>-<hash>.urdf)."""
    path = os.path.join(tempfile.gettempdir(), f"simeval-{kind}-{hashlib.sha1(text.encode()).hexdigest()[:16]}.urdf")
    if not os.path.exists(path):
        tmp = f"{path}.{os.getpid()}.tmp"
        with open(tmp, "w", encoding="utf-8") as f:
            f.write(text)
        os.replace(tmp, path)
    return path
