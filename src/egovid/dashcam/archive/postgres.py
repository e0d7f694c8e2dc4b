"""Connecting to PostgreSQL (psycopg 3), for the catalogue and the advisory locks of an archive
shared by several machines; and URLs fit for messages (password hidden)."""

from __future__ import annotations

import re

from egovid.core.errors import EgovidError


def redact_url(url: str) -> str:
    """``url`` with any password replaced by ``***`` (for messages)."""
    return re.sub(r"(://[^:/@]*:)[^@]*@", r"\1***@", url)


def reason(exc: BaseException) -> str:
    """The last line of a psycopg error (the server's own words), for a message."""
    return (str(exc).strip().splitlines() or ["no reason given"])[-1]


def pg_connect(url: str):
    """An autocommit psycopg connection to ``url``, or one :class:`EgovidError` saying why not."""
    import psycopg  # only archives kept in PostgreSQL need it

    try:
        return psycopg.connect(url, autocommit=True, connect_timeout=10)
    except psycopg.Error as e:
        raise EgovidError(
            f"cannot connect to the PostgreSQL catalogue at {redact_url(url)}: {reason(e)}",
            "check the URL, that the server is running, and the credentials (PGPASSWORD or ~/.pgpass)",
        ) from None
