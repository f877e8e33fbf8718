"""``ugvmap demo`` and ``ugvmap serve``: what ``make demo`` runs."""

from __future__ import annotations

from pathlib import Path

import click

from app.settings import get_settings


@click.command("demo")
@click.option("--shared-data", type=click.Path(path_type=Path, file_okay=False),
              default=Path("../shared/data"), show_default=True,
              help="Sample data folder; a synthetic town is generated when it is absent.")
def demo(shared_data: Path) -> None:
    """Load the demo layers and networks (idempotent) and print an editor token."""
    from ingest.demo import load_demo

    token = load_demo(shared_data, get_settings().data_dir / "demo-editor-token", click.echo)
    click.echo(f"editor token for the web map: {token}")


@click.command("serve")
@click.option("--host", default="127.0.0.1", show_default=True)
@click.option("--port", default=8000, show_default=True, type=int)
@click.option("--workers", default=1, show_default=True, type=int)
def serve(host: str, port: int, workers: int) -> None:
    """Serve the web map, tiles, features and routes over HTTP."""
    import uvicorn

    from app.logs import logging_config

    settings = get_settings()
    uvicorn.run(
        "app.main:create_app",
        factory=True,
        host=host,
        port=port,
        workers=workers,
        log_config=logging_config(settings.log_level),
        access_log=False,
    )
