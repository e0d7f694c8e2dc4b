"""The archive as storage: its folder, catalogue (SQLite or PostgreSQL), blob store and locks."""
