"""aloha_agilex embodiment plugin."""
