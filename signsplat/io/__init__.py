"""File I/O shared by every stage: atomic writes, table schemas, images."""

from signsplat.io.atomic import atomic_path, write_bytes_atomic
from signsplat.io.tables import TABLES, read_table, write_table

__all__ = ["atomic_path", "write_bytes_atomic", "TABLES", "read_table", "write_table"]
