"""In-process inference backends (llama.cpp, ...), each importing its library lazily."""
