"""aloha_agilex embodiment plugin: a dual-arm robot whose URDF/SRDF are generated from parameters.

Public API: :func:`cab_embodiment_aloha.embodiment.factory` (the plugin factory),
:func:`~cab_embodiment_aloha.embodiment.build_spec`, :class:`~cab_embodiment_aloha.params.AlohaParams`.
"""
