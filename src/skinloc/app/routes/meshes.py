"""Meshes: the uploaded skins, listed and received (counted as they arrive, at most 64 MB)."""

from __future__ import annotations

import asyncio
import os
from pathlib import Path
from typing import Any

from fastapi import HTTPException, Query, Request

from skinloc.app.routes.common import PageContext, actions_router, received_upload
from skinloc.errors import SkinlocError

MAX_UPLOAD_BYTES = 64 * 1024 * 1024
MESH_SUFFIXES = (".obj", ".stl", ".ply")


def add_routes(ctx: PageContext) -> None:
    """``GET /api/meshes`` and ``POST /api/meshes?filename=`` (the file is the body)."""
    app, workspace = ctx.app, ctx.workspace
    router = actions_router()

    @router.get("/api/meshes")
    def meshes() -> list[dict[str, Any]]:
        return _list_meshes(workspace.mesh_dir)

    @router.post("/api/meshes")
    async def upload_mesh(
        request: Request,
        filename: str = Query(..., max_length=255),
    ) -> dict[str, Any]:
        name = _mesh_name(filename)
        declared = request.headers.get("content-length", "")
        if declared.isdigit() and int(declared) > MAX_UPLOAD_BYTES:
            raise HTTPException(413, f"mesh file too large ({int(declared)} bytes; at most 64 MB)")
        folder = workspace.mesh_dir
        # Into a hidden file beside the meshes: a stored mesh of that name is replaced only by
        # one that loads.
        suffix = Path(name).suffix
        async with received_upload(request, folder, suffix, MAX_UPLOAD_BYTES, "mesh file") as (
            tmp,
            size,
        ):
            if size == 0:
                raise ValueError(f"{name} is empty: upload an OBJ, STL or PLY mesh")
            return await asyncio.to_thread(_install_mesh, tmp, folder / name)

    app.include_router(router)


def _mesh_name(filename: str) -> str:
    """The stored name of an uploaded mesh (no folders, a mesh suffix, not hidden)."""
    name = Path(filename.replace("\\", "/")).name
    if Path(name).suffix.lower() not in MESH_SUFFIXES or name.startswith("."):
        raise ValueError(f"upload an OBJ, STL or PLY mesh, not {name[:80]!r}")
    return name


def _list_meshes(folder: Path) -> list[dict[str, Any]]:
    """The uploaded meshes, by name."""
    if not folder.is_dir():
        return []
    return [
        {"name": p.name, "bytes": p.stat().st_size}
        for p in sorted(folder.iterdir())
        if p.suffix.lower() in MESH_SUFFIXES and not p.name.startswith(".") and p.is_file()
    ]


def _install_mesh(tmp: Path, path: Path) -> dict[str, Any]:
    """Load the uploaded ``tmp``; only if it is a mesh does it replace ``path`` (atomically)."""
    from skinloc.geometry.mesh import load_mesh

    try:
        mesh = load_mesh(tmp)
    except (SkinlocError, ValueError) as exc:
        # Name the file as the person did, not the hidden file it was received into.
        raise ValueError(str(exc).replace(str(tmp), path.name)) from None
    os.replace(tmp, path)
    return {
        "name": path.name,
        "n_faces": len(mesh.faces),
        "extents_mm": [round(float(e) * 1e3, 1) for e in mesh.extents],
    }
