"""The reference harness: a provider-neutral agent loop, the paper's context policy and one
provider adapter per API (each through its official SDK)."""


def cab_preload() -> None:
    """The fork server's hook (cab_core.sweep.zygote): what the OpenAI SDK imports only when a client
    is made and first used (its chat resources, its HTTP transport and TLS modules, about 60
    modules), imported once in the server instead of in every worker. No request is sent and no
    thread started: the client is made, its chat resource touched, and closed."""
    import importlib.util

    if importlib.util.find_spec("openai") is None:
        return
    import openai

    client = openai.OpenAI(api_key="cab-preload", base_url="http://127.0.0.1:9/v1", max_retries=0)
    try:
        client.chat.completions  # noqa: B018  (the SDK imports its resources on first access)
    finally:
        client.close()
