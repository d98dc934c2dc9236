"""A conversational agent: speech in, a vision-language model answers about the camera, speech out."""

from agents.clients import OllamaClient, RoboMLHTTPClient
from agents.components import VLM, SpeechToText, TextToSpeech
from agents.config import SpeechToTextConfig, TextToSpeechConfig
from agents.models import OllamaModel, SpeechT5, Whisper
from agents.ros import Launcher, Topic

audio_in = Topic(name="audio0", msg_type="Audio")
text_query = Topic(name="text0", msg_type="String")

whisper = Whisper(name="whisper")
whisper_client = RoboMLHTTPClient(whisper)

speech_to_text = SpeechToText(
    inputs=[audio_in],
    outputs=[text_query],
    model_client=whisper_client,
    trigger=audio_in,
    config=SpeechToTextConfig(enable_vad=True, min_silence_duration_ms=400),
    component_name="speech_to_text",
)

image0 = Topic(name="image_raw", msg_type="Image")
text_answer = Topic(name="text1", msg_type="String")

llava = OllamaModel(name="llava", checkpoint="llava:latest")
llava_client = OllamaClient(llava)

mllm = VLM(
    inputs=[text_query, image0],
    outputs=[text_answer],
    model_client=llava_client,
    trigger=text_query,
    component_name="vqa",
)
mllm.set_topic_prompt(text_query, template="""You are an amazing and funny robot.
Answer the following about this image: {{ text0 }}""")

speecht5 = SpeechT5(name="speecht5")
speecht5_client = RoboMLHTTPClient(speecht5)
text_to_speech = TextToSpeech(
    inputs=[text_answer],
    trigger=text_answer,
    model_client=speecht5_client,
    config=TextToSpeechConfig(play_on_device=True),
    component_name="text_to_speech",
)

launcher = Launcher()
launcher.enable_ui(inputs=[text_query], outputs=[text_answer, image0])
launcher.add_pkg(components=[speech_to_text, mllm, text_to_speech])
launcher.bringup()
