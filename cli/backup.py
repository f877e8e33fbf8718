"""``ugvmap backup DIR`` and ``ugvmap restore DIR``: the database and the raster store as one
consistent copy (see :mod:`cli.ops.backup` for how they are kept consistent)."""

from __future__ import annotations

import sys
from pathlib import Path

import click
from tqdm import tqdm


def _bar(desc: str) -> tqdm:
    return tqdm(desc=desc, unit="B", unit_scale=True, disable=not sys.stderr.isatty())


@click.command("backup")
@click.argument("directory", type=click.Path(file_okay=False, path_type=Path))
def backup(directory: Path) -> None:
    """Back up the database (pg_dump) and the raster store into a new DIRECTORY."""
    from app.jobs.recorder import JobRecorder
    from app.settings import get_settings
    from app.tiles.store import store_root
    from cli.ops.backup import backup as run_backup

    settings = get_settings()
    with JobRecorder("backup", str(directory)) as job, _bar("backup") as bar:

        def progress(step: str, done: int) -> None:
            bar.n = done
            bar.set_postfix_str(step[-40:])
            bar.refresh()

        summary = run_backup(directory, settings.database_url, store_root(), progress)
        job.progress(1.0, f"{summary.files} files")
    click.echo(f"backup in {summary.directory}: schema {summary.revision}, "
               f"{summary.files} raster files, {summary.bytes / 1e6:.1f} MB, "
               + ", ".join(f"{v} {k}" for k, v in summary.counts.items()))
    if summary.external:
        click.echo(f"warning: {summary.external} raster references lie outside the store "
                   "and are not in the backup", err=True)


@click.command("restore")
@click.argument("directory", type=click.Path(exists=True, file_okay=False, path_type=Path))
def restore(directory: Path) -> None:
    """Restore a backup DIRECTORY into an empty database and the configured raster store."""
    from app.settings import get_settings
    from app.tiles.store import store_root
    from cli.ops.backup import restore as run_restore

    with _bar("restore") as bar:

        def progress(step: str, done: int) -> None:
            bar.n = done
            bar.set_postfix_str(step[-40:])
            bar.refresh()

        summary = run_restore(directory, get_settings().database_url, store_root(), progress)
    click.echo(f"restored {summary.directory}: schema {summary.revision} (migrated to head), "
               f"{summary.files} raster files into {store_root()}, "
               + ", ".join(f"{v} {k}" for k, v in summary.counts.items()))
