"""The multimodal chat handlers of llama-cpp-python a :class:`~embagents.models.VLMModel` may name.

Keys are what a declaration says (``chat_handler="llava15"``), values the handler
classes of ``llama_cpp.llama_chat_format``; the installed version may offer fewer
(:func:`embagents.models.backends.vlm.handler_class` says which).

>>> VLM_HANDLERS["moondream"]
'MoondreamChatHandler'
"""

from __future__ import annotations

__all__ = ["VLM_HANDLERS"]

VLM_HANDLERS = {
    "llava15": "Llava15ChatHandler", "llava16": "Llava16ChatHandler", "moondream": "MoondreamChatHandler",
    "nanollava": "NanoLlavaChatHandler", "qwen25vl": "Qwen25VLChatHandler", "minicpmv26": "MiniCPMv26ChatHandler",
    "llama3vision": "Llama3VisionAlphaChatHandler", "gemma4": "Gemma4ChatHandler",
}
