"""``impactcell serve | submit | status | demo``: the service from the command line."""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

from service.api.settings import DEFAULT_URL
from service.cli.common import (
    Failure,
    check_port_free,
    error_exit_status,
    positive_int,
    probe_scheduler,
    probe_service,
    settings_from_flags,
)

__all__ = ["add_commands"]


def _cmd_serve(args: argparse.Namespace) -> int:
    import uvicorn

    from service.api.app import create_app

    settings = settings_from_flags(
        host=args.host, port=args.port, data_dir=args.data_dir, scheduler=args.scheduler,
        database_url=args.database_url, workers=args.workers,
    )  # fmt: skip
    # uvicorn binds only after the start-up (catalogue, job runner): a taken port fails now.
    check_port_free(settings.host, settings.port)
    if settings.scheduler:
        try:  # not fatal: the service connects when a study first needs the cluster
            probe_scheduler(settings.scheduler)
        except Failure as exc:
            print(f"impactcell: warning: {exc}; studies wait until it is up", file=sys.stderr)
    catalogue = _without_password(settings.catalogue_url())
    _open_catalogue(settings, catalogue)
    print(
        f"impactcell service on http://{settings.host}:{settings.port} "
        f"(data {settings.data_dir}, catalogue {catalogue}, "
        f"cluster {settings.scheduler or 'embedded LocalCluster'}, "
        f"auth {'on' if settings.api_token else 'off'})",
        file=sys.stderr,
    )
    uvicorn.run(create_app(settings), host=settings.host, port=settings.port,
                log_level=args.log_level)  # fmt: skip
    return 0


def _open_catalogue(settings: Any, shown: str) -> None:
    """Open (and migrate) the catalogue once before the server starts: a URL that is none or a
    database that cannot be reached ends ``serve`` with one line (exit 2 or 1), not with the
    server's start-up traceback."""
    from sqlalchemy.exc import ArgumentError, SQLAlchemyError

    from service.api.catalogue import Catalogue
    from service.api.migrate import CatalogueError
    from service.cli.common import catalogue_error

    settings.data_dir.mkdir(parents=True, exist_ok=True)  # the default catalogue's folder
    try:
        Catalogue(settings.catalogue_url()).close()
    except ArgumentError:
        raise ValueError(
            f"database URL {shown} is not one SQLAlchemy reads (e.g. "
            "postgresql+psycopg://user:password@host:5432/name or sqlite:///path/catalogue.sqlite)"
        ) from None
    except (CatalogueError, SQLAlchemyError) as exc:
        raise Failure(catalogue_error(exc, shown)) from None


def _without_password(url: str) -> str:
    """A database URL fit to print: SQLAlchemy's rendering with the password hidden."""
    from sqlalchemy import make_url
    from sqlalchemy.exc import ArgumentError

    try:
        return make_url(url).render_as_string(hide_password=True)
    except ArgumentError:  # not a URL SQLAlchemy reads (the catalogue will say so): show none
        return "***"


class _ProgressBar:
    """A tqdm bar fed with the records ``Client.wait`` polls (the client itself has no tqdm)."""

    def __init__(self) -> None:
        self.bar: Any = None

    def __call__(self, rec: Any) -> None:
        from tqdm import tqdm

        if self.bar is None:
            self.bar = tqdm(total=rec["points_total"], unit="pt", desc=rec["name"],
                            file=sys.stderr, dynamic_ncols=True)  # fmt: skip
        self.bar.update(rec["points_done"] - self.bar.n)
        waiting = rec["status"] == "waiting" and rec.get("error")  # paused by an outage: why
        self.bar.set_postfix_str(f"{rec['status']}: {rec['error']}" if waiting else rec["status"])

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _wait(client: Any, study_id: str, progress: bool) -> dict[str, Any]:
    """``client.wait``, with a progress bar on stderr unless ``progress`` is false."""
    bar = _ProgressBar() if progress else None
    try:
        return client.wait(study_id, progress=bar or False)
    finally:
        if bar is not None:
            bar.close()


def _client(args: argparse.Namespace) -> Any:
    from service.client import Client

    # --url and --token over IMPACTCELL_URL and IMPACTCELL_API_TOKEN ("": no token).
    settings = settings_from_flags({"api_token": "--token"}, url=args.url, api_token=args.token)
    # httpx would wait its whole timeout for a host that does not answer: probe first.
    probe_service(settings.url, "--url" if args.url is not None else "IMPACTCELL_URL")
    return Client(settings.url, token=settings.api_token or "")


def _cmd_submit(args: argparse.Namespace) -> int:
    from service.client import ClientError, StudyFailed
    from service.studies.files import read_study_file
    from service.studies.shipped import resolve_study_file

    study = resolve_study_file(args.study)
    _readable(study)
    # Read here, not by the service: a base-amplitude table file beside the study is read into
    # its definition (the service never opens files a study names). Errors are ValueErrors:
    # one line, exit 2.
    definition = read_study_file(study)
    with _client(args) as c:
        try:
            rec = c.submit(definition)
            # An adaptive study's total is the most it may compute: it stops where it has enough.
            adaptive = isinstance(definition, dict) and definition.get("adaptive") is not None
            total = f"{'up to ' if adaptive else ''}{rec['points_total']:,} points"
            print(f"{rec['id']}  {rec['name']}  {rec['status']}  {total}")
            if args.wait:
                rec = _wait(c, rec["id"], progress=not args.no_progress)
                print(f"{rec['id']}  finished in {rec['wall_s'] or 0:.1f} s, "
                      f"{rec['points_total']:,} points, {rec['points_failed']} failed")  # fmt: skip
        except StudyFailed as exc:
            raise Failure(str(exc)) from None
        except ClientError as exc:
            return _print_problems(exc)
    return 0


def _readable(path: Path) -> None:
    """ValueError (exit 2) for a study file that cannot be read as UTF-8 text."""
    try:
        path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        reason = getattr(exc, "strerror", None) or str(exc)
        raise ValueError(f"cannot read study file {path}: {reason}") from None


def _print_problems(exc: Any) -> int:
    """The service's error answer on stderr, each problem once; exit 1 for its own failures
    (5xx), else 2."""
    code, message = error_exit_status(exc)
    print(f"impactcell: error: {message}".replace("\n", "\n  "), file=sys.stderr)
    return code


def _cmd_status(args: argparse.Namespace) -> int:
    from service.client import ClientError

    with _client(args) as c:
        try:
            recs = [c.get(args.id)] if args.id else c.list(limit=args.limit)
        except ClientError as exc:
            return _print_problems(exc)
    if args.json:
        print(json.dumps(recs[0] if args.id else recs))
        return 0
    for r in recs:
        pct = 100.0 * r["progress"]
        print(f"{r['id']}  {r['status']:<9}  {pct:5.1f}%  {r['points_done']:>9,}/"
              f"{r['points_total']:<9,}  failed {r['points_failed']:<6,} {r['name']}")  # fmt: skip
        if args.id:
            for k in ("submitted_at", "started_at", "finished_at", "wall_s", "error"):
                print(f"  {k:<13} {r[k]}")
            # outcomes of the points (counted when the study finishes)
            print(f"  {'irregular':<13} {r.get('points_irregular', 0):,}")
            print(f"  {'unsettled':<13} {r.get('points_unsettled', 0):,}")
            for f in r["failures"][:5]:
                print(f"  failed point {f['coords']}: {f['reason']}")
    return 0


def _cmd_demo(args: argparse.Namespace) -> int:
    from service.api.server import ServerThread
    from service.client import Client
    from service.studies.dataset import encoding, write_netcdf
    from service.studies.shipped import resolve_study_file

    study = resolve_study_file(args.study or ("paper-fig5-gaps" if args.full else "demo-fig5"))
    _readable(study)
    out = _output_folder(args.out)
    # The demo's own service: on a free loopback port, without a token whatever the environment.
    settings = settings_from_flags(
        host="127.0.0.1", port=0, data_dir=out / "data", workers=args.workers
    ).model_copy(update={"api_token": None})
    _open_catalogue(settings, _without_password(settings.catalogue_url()))
    t0 = time.perf_counter()
    server = ServerThread(settings).start()
    print(f"service on {server.url} (embedded LocalCluster), data in {settings.data_dir}",
          file=sys.stderr)  # fmt: skip
    try:
        with Client(server.url) as c:
            rec = c.submit(study)
            print(f"submitted {study.name}: {rec['points_total']:,} points, id {rec['id']}",
                  file=sys.stderr)  # fmt: skip
            rec = _wait(c, rec["id"], progress=not args.no_progress)
            ds = c.dataset(rec["id"])
            nc = out / f"{rec['name']}.nc"
            write_netcdf(ds, nc, encoding(ds))
            sel = _demo_selection(ds, "gamma_r", "gap")
            # self-describing: variable, axes with units, threshold and the slice it used
            doc = c.bandgap_json(rec["id"], x="gamma_r", y="gap", nearest=True, **sel)
            png = out / "bandgap.png"
            png.write_bytes(c.plot(rec["id"], "bandgap", x="gamma_r", y="gap", **sel))
            (out / "transmittance.png").write_bytes(
                c.plot(rec["id"], "transmittance", x="gamma_r", hue="gap", **sel)
            )
            (out / "bandgap.json").write_text(json.dumps(doc, indent=1), encoding="utf-8")
            # What the impacts add: the same cell without stops (Γ_lin) and Γ − Γ_lin.
            lin = c.bandgap_json(rec["id"], x="gamma_r", y="gap", nearest=True,
                                 variable="transmittance_linear_db", **sel)  # fmt: skip
            effect = c.bandgap_json(
                rec["id"], x="gamma_r", y="gap", threshold_db=-1.0, nearest=True,
                variable="impact_effect_db", **sel,
            )  # fmt: skip
            (out / "impact_effect.json").write_text(json.dumps(effect, indent=1), encoding="utf-8")
            effect_png = c.plot(rec["id"], "bandgap", x="gamma_r", y="gap", threshold_db=-1.0,
                                variable="impact_effect_db", **sel)  # fmt: skip
            (out / "impact_effect.png").write_bytes(effect_png)
    finally:
        server.stop()
    print(f"{rec['points_total']:,} points in {time.perf_counter() - t0:.1f} s "
          f"({rec['points_failed']} failed, {rec['points_irregular']} irregular, "
          f"{rec.get('points_unsettled', 0)} unsettled)")  # fmt: skip
    for line in _demo_lines(doc, lin, effect):
        print(line)
    print(f"wrote {nc.name}, bandgap.png, transmittance.png, bandgap.json, impact_effect.png, "
          "impact_effect.json to")  # fmt: skip
    print(out)
    return 0


def _spans(bands: Any) -> str:
    return ", ".join(f"{a:.3g}–{b:.3g}" for a, b in bands) or "none"


def _demo_lines(doc: dict[str, Any], lin: dict[str, Any], effect: dict[str, Any]) -> list[str]:
    """Per gap: Γ's bands, the bands of the cell without stops, and where the impacts add (or
    remove) more than 1 dB of attenuation: what the stops widen, narrow or create."""
    import numpy as np

    from service.analysis.bands import band_edges

    x = np.asarray(effect["coords"][effect["x"]], dtype=float)
    values = np.array(effect["impact_effect_db"], dtype=float)  # None -> nan
    out = []
    for k, band in enumerate(doc["edges"]):
        row = values[k] if values.ndim == 2 else values
        # impact effect > +1 dB: attenuation the impacts take away
        less = [(b.start, b.stop) for b in band_edges(x, -row, -1.0)]
        out.append(
            f"  gap {band['y']:g}: Γ < 0 dB for γ_r in {_spans(band['bands'])}; without stops "
            f"{_spans(lin['edges'][k]['bands'])}; impacts add > 1 dB of attenuation for γ_r in "
            f"{_spans(effect['edges'][k]['bands'])}, remove > 1 dB in {_spans(less)}"
        )
    return out


def _output_folder(text: str) -> Path:
    """The ``--out`` folder, created and writable, or ValueError (exit 2) before any work."""
    out = Path(text).resolve()
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ValueError(f"--out {text}: cannot create the folder: {exc.strerror or exc}") from None
    if not os.access(out, os.W_OK | os.X_OK):
        raise ValueError(f"--out {text}: the folder is not writable")
    return out


def _demo_selection(ds: Any, x: str, y: str) -> dict[str, float]:
    # The map is Γ over γ_r × gap; other axes are taken at a representative value (θ = 0.3).
    sel = {}
    for d in ds.dims:
        if d in (x, y, "stop") or ds.sizes[d] == 1:
            continue
        vals = ds[d].values
        sel[str(d)] = float(0.3 if d == "theta" and (abs(vals - 0.3) < 1e-9).any() else vals[0])
    return sel


def add_commands(sub: argparse._SubParsersAction) -> None:
    """Add ``serve``, ``submit``, ``status`` and ``demo``."""
    p = sub.add_parser(
        "serve",
        help="run the REST service (uvicorn)",
        description="Run the REST service and its web page: studies are submitted, run on the "
        "dask cluster (an embedded LocalCluster unless --scheduler), catalogued in the "
        "database, and their results served as NetCDF, JSON, CSV and figures. Settings come "
        "from these flags over IMPACTCELL_* variables (docs/service.md).",
    )
    p.add_argument("--host", default=None, help="bind address (default 127.0.0.1)")
    p.add_argument("--port", type=int, default=None, help="port (default 8000)")
    p.add_argument("--data-dir", default=None, help="data folder (default ./data)")
    p.add_argument(
        "--scheduler",
        default=None,
        help="dask scheduler tcp://host:port (default: embedded LocalCluster)",
    )
    p.add_argument(
        "--database-url",
        default=None,
        help="catalogue SQLAlchemy URL (default: SQLite in the data dir)",
    )
    p.add_argument(
        "--workers",
        type=positive_int,
        default=None,
        help="embedded cluster processes (default: one per core)",
    )
    p.add_argument(
        "--log-level",
        default="info",
        choices=["critical", "error", "warning", "info", "debug"],
        help="uvicorn's log level",
    )
    p.set_defaults(func=_cmd_serve)  # fmt: skip

    url_help = f"service URL (default $IMPACTCELL_URL or {DEFAULT_URL})"
    p = sub.add_parser(
        "submit",
        help="submit a study file to the service",
        description="Submit a study file (or a shipped study) to a running service and print "
        "its id; with --wait, follow it until it finishes. An identical study submitted again "
        "is the same study. `impactcell run` runs a study without a service.",
    )
    p.add_argument(
        "study", help="study file (.yaml, .yml or .json) or a shipped study's name (quick)"
    )
    p.add_argument("--url", default=None, help=url_help)
    p.add_argument("--token", default=None, help="bearer token (default $IMPACTCELL_API_TOKEN)")
    p.add_argument("--wait", action="store_true", help="wait until it finishes (progress bar)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar with --wait")
    p.set_defaults(func=_cmd_submit)

    p = sub.add_parser(
        "status",
        help="status of one study, or the latest studies",
        description="The status and progress of one study of a running service (with its "
        "timings, outcome counts and a sample of failed points), or of its latest studies.",
    )
    p.add_argument("id", nargs="?", default=None, help="study id (default: list studies)")
    p.add_argument("--url", default=None, help=url_help)
    p.add_argument("--token", default=None, help="bearer token (default $IMPACTCELL_API_TOKEN)")
    p.add_argument("--limit", type=positive_int, default=20, help="studies to list")
    p.add_argument("--json", action="store_true", help="JSON output")
    p.set_defaults(func=_cmd_status)

    p = sub.add_parser(
        "demo",
        help="start the service in-process, run the Figure-5 study, write the bandgap map",
        description="Start the service in this process on a free loopback port, submit the "
        "demo study through the Python client, and write to --out its NetCDF dataset, the "
        "bandgap and impact-effect maps (PNG and JSON with the band edges) and the "
        "transmittance curves; print the bands per gap.",
    )
    p.add_argument("--out", default="impactcell-demo", help="output folder")
    p.add_argument(
        "--full",
        action="store_true",
        help="the full paper-fig5-gaps study (5,820 points) instead of the demo cut",
    )
    p.add_argument(
        "--study",
        default=None,
        help="another study file or shipped study name (default: demo-fig5, with --full "
        "paper-fig5-gaps)",
    )
    p.add_argument(
        "--workers",
        type=positive_int,
        default=None,
        help="embedded cluster processes (default: one per core)",
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=_cmd_demo)  # fmt: skip
