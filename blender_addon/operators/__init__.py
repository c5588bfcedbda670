"""One operator per module, named after its ``bl_idname`` (``divas.<verb_noun>`` in
``<verb_noun>.py``; the session-step operators share :mod:`.session_base`);
:data:`CLASSES` is registered in order, unregistered in reverse."""

from __future__ import annotations

from . import (
    activate_camera,
    delete_selected,
    export_objects,
    export_selection,
    extract_selection,
    hide_selected,
    import_cameras,
    import_density_grid,
    import_splats,
    resume_session,
    reveal_hidden,
    segment_modal,
    segmented_volume,
    select_all,
    select_by_attribute,
    select_gesture,
    select_grow,
    select_region,
    select_sphere,
    separate_selected,
    session_accept,
    session_add_anchor,
    session_click,
    session_finish_object,
    session_reset,
    session_sync,
    session_undo,
    session_viewport_click,
    start_session,
)

CLASSES = (
    import_splats.DIVAS_OT_import_splats,
    import_density_grid.DIVAS_OT_import_density_grid,
    import_cameras.DIVAS_OT_import_cameras,
    export_selection.DIVAS_OT_export_selection,
    extract_selection.DIVAS_OT_extract_selection,
    segmented_volume.DIVAS_OT_segmented_volume,
    activate_camera.DIVAS_OT_activate_camera,
    start_session.DIVAS_OT_start_session,
    segment_modal.DIVAS_OT_segment_modal,
    session_click.DIVAS_OT_session_click,
    session_viewport_click.DIVAS_OT_session_viewport_click,
    session_add_anchor.DIVAS_OT_session_add_anchor,
    session_accept.DIVAS_OT_session_accept,
    session_sync.DIVAS_OT_session_sync,
    session_undo.DIVAS_OT_session_undo,
    session_reset.DIVAS_OT_session_reset,
    session_finish_object.DIVAS_OT_session_finish_object,
    resume_session.DIVAS_OT_resume_session,
    export_objects.DIVAS_OT_export_objects,
    select_region.DIVAS_OT_select_region,
    select_gesture.DIVAS_OT_select_gesture,
    select_sphere.DIVAS_OT_select_sphere,
    select_all.DIVAS_OT_select_all,
    select_grow.DIVAS_OT_select_grow,
    select_by_attribute.DIVAS_OT_select_by_attribute,
    delete_selected.DIVAS_OT_delete_selected,
    hide_selected.DIVAS_OT_hide_selected,
    reveal_hidden.DIVAS_OT_reveal_hidden,
    separate_selected.DIVAS_OT_separate_selected,
)

#: (menu type name, draw function) pairs appended on register.
MENU_ENTRIES = (
    ("TOPBAR_MT_file_import", import_splats.menu_func),
    ("TOPBAR_MT_file_import", import_density_grid.menu_func),
    ("TOPBAR_MT_file_import", import_cameras.menu_func),
    ("TOPBAR_MT_file_export", export_selection.menu_func),
)
