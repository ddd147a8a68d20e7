"""`shsas keys create|list|revoke`: API keys of the HTTP service (stored hashed in the job store)."""

from __future__ import annotations

import argparse
from datetime import UTC, datetime


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "keys", help="create, list or revoke API keys of the HTTP service",
        description="Manage the API keys of the shsas service, in the job store named by "
        "SHSAS_DATABASE_URL / SHSAS_DATA_DIR. Each job belongs to the key that submitted it. The secret is "
        "printed once at creation and stored only as a hash. While no key is active the service serves "
        "loopback clients only.")
    ksub = p.add_subparsers(dest="keys_command", metavar="ACTION", required=True)
    c = ksub.add_parser("create", help="create a key and print it once")
    c.add_argument("name", help="a label for the key's holder, e.g. alice or ci")
    c.set_defaults(func=create)
    ls = ksub.add_parser("list", help="list keys (ids, names, created, revoked)")
    ls.set_defaults(func=list_keys)
    r = ksub.add_parser("revoke", help="revoke a key by id; its jobs stay but the key stops working")
    r.add_argument("key_id", help="key id as shown by `shsas keys list`")
    r.set_defaults(func=revoke)


def _store():
    from shsas_core.common.errors import ShsasError

    try:
        from jobs.settings import get_settings
        from jobs.store import JobStore
    except ImportError as exc:
        raise ShsasError(f"keys: the service extra is not installed ({exc.name}); "
                         "pip install 'shsas[service]'") from None
    return JobStore.from_settings(get_settings())


def _ts(t: float | None) -> str:
    return "-" if t is None else datetime.fromtimestamp(t, UTC).strftime("%Y-%m-%d %H:%M:%SZ")


def create(args: argparse.Namespace) -> int:
    rec, token = _store().create_key(args.name)
    print(f"created key {rec.id} ({rec.name}); send it as 'Authorization: Bearer <key>'. "
          "It is shown only now:")
    print(token)
    return 0


def list_keys(args: argparse.Namespace) -> int:
    keys = _store().list_keys()
    if not keys:
        print("no keys (the service serves loopback clients only)")
    for k in keys:
        print(f"{k.id}  {k.name:<20}  created {_ts(k.created_at)}  "
              f"{'revoked ' + _ts(k.revoked_at) if k.revoked_at else 'active'}")
    return 0


def revoke(args: argparse.Namespace) -> int:
    from shsas_core.common.errors import ShsasError

    if not _store().revoke_key(args.key_id):
        raise ShsasError(f"keys: no active key with id {args.key_id!r} (see `shsas keys list`)")
    print(f"revoked key {args.key_id}")
    return 0
