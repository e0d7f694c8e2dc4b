"""The archive as storage: its folder (store), catalogue (SQLite or PostgreSQL; catalogue_file:
the SQLite file's checks, backup and salvage; postgres: connecting), the fleet tables (fleetstore),
blob store (blobs), locks, and reference chains between drives (references)."""
