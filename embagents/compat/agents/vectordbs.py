"""EmbodiedAgents' ``agents.vectordbs``: the vector database a ``ChromaClient`` names.

Here the vector database is built in (SQLite: :mod:`embagents.components.memory_store`
for a Memory, the routes inside a SemanticRouter), so ``ChromaDB()`` only says which
embeddings the client gives: all-MiniLM-L6-v2 in a local model actor, or, with
``embeddings="ollama"``, the Ollama server's embedding model ``checkpoint``.

Example::

    >>> from embagents.compat.agents.clients import ChromaClient
    >>> ChromaClient(db=ChromaDB()).db.embeddings
    'sentence-transformers'
"""

from __future__ import annotations

from embagents.compat._core import CompatError

__all__ = ["ChromaDB"]


class ChromaDB:
    """EmbodiedAgents' ChromaDB: which embeddings the database uses (its storage is built in here)."""

    def __init__(self, username: str | None = None, password: str | None = None, embeddings: str = "sentence-transformers",
                 checkpoint: str = "bge-large:latest", ollama_host: str = "127.0.0.1", ollama_port: int = 11434,
                 init_timeout: int = 600) -> None:
        if embeddings not in ("ollama", "sentence-transformers"):
            raise CompatError(f"ChromaDB: embeddings must be 'ollama' or 'sentence-transformers', got {embeddings!r}")
        self.username, self.password = username, password
        self.embeddings, self.checkpoint = embeddings, checkpoint
        self.ollama_host, self.ollama_port, self.init_timeout = ollama_host, int(ollama_port), int(init_timeout)

    def __repr__(self) -> str:
        return f"ChromaDB(embeddings={self.embeddings!r}, checkpoint={self.checkpoint!r})"
