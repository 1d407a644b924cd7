"""`ropemon user add|remove|list USERS.toml`: the web face's users (docs/web.md).

    ropemon user add USERS.toml NAME --role operator     asks for the password twice
    ropemon user add USERS.toml NAME --role engineer --password-stdin   (one line on stdin)
    ropemon user passwd USERS.toml NAME                  a new password, the role kept
    ropemon user remove USERS.toml NAME
    ropemon user list USERS.toml

The file is written with mode 0600 and holds argon2id hashes only. No user is shipped: a
station's web face lets nobody act until its engineer adds one. A running station reads the
file again when it changes: a new password, a new role or a removal ends that user's sessions.
"""
from __future__ import annotations

import argparse
import getpass
import sys


def add_arguments(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="user_command", metavar="ACTION")
    sub.required = True
    a = sub.add_parser("add", help="add a user, or set an existing user's role and password")
    a.add_argument("users", help="the users file (web.users in station.toml); made if absent")
    a.add_argument("name", help="1-32 of a-z, 0-9, '_', '.', '-', starting with a letter")
    a.add_argument("--role", required=True, choices=("viewer", "operator", "engineer"),
                   help="viewer: sees the pages; operator: acknowledges and shelves alarms, accepts a "
                        "rewound node; engineer: also takes alarms out of service")
    a.add_argument("--password-stdin", action="store_true",
                   help="read the password from the first line of stdin instead of asking twice")
    pw = sub.add_parser("passwd", help="set a user's password (the role kept); ends the user's web sessions")
    pw.add_argument("users")
    pw.add_argument("name")
    pw.add_argument("--password-stdin", action="store_true",
                    help="read the password from the first line of stdin instead of asking twice")
    r = sub.add_parser("remove", help="remove a user")
    r.add_argument("users")
    r.add_argument("name")
    ls = sub.add_parser("list", help="list the users and their roles")
    ls.add_argument("users")


def _password(args: argparse.Namespace) -> str:
    if args.password_stdin:
        line = sys.stdin.readline()
        return line[:-1] if line.endswith("\n") else line
    if not sys.stdin.isatty():
        raise ValueError("no terminal to ask for the password: give --password-stdin")
    first = getpass.getpass(f"password for {args.name}: ")
    second = getpass.getpass("again: ")
    if first != second:
        raise ValueError("the two passwords differ")
    return first


def run(args: argparse.Namespace) -> int:
    try:
        from ropemon.station.users import UsersError, add_user, load_users, remove_user, set_password
    except ImportError as e:
        print(f"ropemon user: needs the web face's libraries: pip install 'ropemon[web]' ({e})", file=sys.stderr)
        return 2
    try:
        if args.user_command == "add":
            user = add_user(args.users, args.name, args.role, _password(args))
            print(f"ropemon user: {user.name} ({user.role}) in {args.users}", file=sys.stderr)
        elif args.user_command == "passwd":
            if args.name not in load_users(args.users):
                print(f"ropemon user: no user {args.name!r} in {args.users}", file=sys.stderr)
                return 1
            user = set_password(args.users, args.name, _password(args))
            print(f"ropemon user: new password for {user.name} ({user.role}) in {args.users}", file=sys.stderr)
        elif args.user_command == "remove":
            if not remove_user(args.users, args.name):
                print(f"ropemon user: no user {args.name!r} in {args.users}", file=sys.stderr)
                return 1
            print(f"ropemon user: removed {args.name} from {args.users}", file=sys.stderr)
        else:
            for name, u in sorted(load_users(args.users).items()):
                print(f"{name}\t{u.role}")
    except (UsersError, ValueError, OSError) as e:
        print(f"ropemon user: {e}", file=sys.stderr)
        return 2
    return 0
