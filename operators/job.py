"""Long work as a step generator: synchronous from scripts and in background mode
(``execute``), modal with a timer from the UI (``invoke``), so the window-manager
progress bar moves and Esc cancels between steps.

A subclass implements ``steps(scene)``: a generator yielding (fraction, message) after
each piece of work. It must change the scene only in its last step, and restore anything
temporary (e.g. the current frame) in a ``finally``: closing the generator (Esc) then
leaves the scene exactly as it was.
"""
import traceback

import bpy

from ..irad_addon.bake import BakeError


class JobOperator:
    bl_options = {'REGISTER', 'UNDO'}
    _running = False          # one job at a time (they share the scene and the frame)

    @classmethod
    def poll(cls, context):
        if context.scene is None:
            return False
        if JobOperator._running:
            cls.poll_message_set("An Instant Radiosity job is already running (Esc cancels it)")
            return False
        return True

    # ------------------------------------------------------------- synchronous
    def execute(self, context):
        wm = context.window_manager
        wm.progress_begin(0, 100)
        JobOperator._running = True
        try:
            for fraction, _message in self.steps(context.scene):
                wm.progress_update(int(100 * fraction))
        except BakeError as error:
            self.report({'ERROR'}, str(error))
            return {'CANCELLED'}
        except Exception as error:          # a bug of ours: say so, keep the trace
            traceback.print_exc()
            self.report({'ERROR'}, f"Instant Radiosity failed: {type(error).__name__}: {error}")
            return {'CANCELLED'}
        finally:
            JobOperator._running = False
            wm.progress_end()
        return {'FINISHED'}

    # ------------------------------------------------------------------- modal
    def invoke(self, context, event):
        if bpy.app.background or context.window is None:
            return self.execute(context)
        wm = context.window_manager
        # The scene is bound now: a context must not be kept across modal events.
        self._steps = self.steps(context.scene)
        self._timer = wm.event_timer_add(0.01, window=context.window)
        wm.modal_handler_add(self)
        wm.progress_begin(0, 100)
        JobOperator._running = True
        return {'RUNNING_MODAL'}

    def modal(self, context, event):
        if event.type == 'ESC' and event.value == 'PRESS':
            self._steps.close()                 # runs the generator's finally blocks
            self._finish(context)
            self.report({'WARNING'}, f"{self.bl_label}: cancelled, nothing was changed")
            return {'CANCELLED'}
        if event.type != 'TIMER':
            return {'PASS_THROUGH'}
        try:
            fraction, message = next(self._steps)
        except StopIteration:
            self._finish(context)
            return {'FINISHED'}
        except BakeError as error:
            self._finish(context)
            self.report({'ERROR'}, str(error))
            return {'CANCELLED'}
        except Exception as error:
            traceback.print_exc()
            self._finish(context)
            self.report({'ERROR'}, f"Instant Radiosity failed: {type(error).__name__}: {error}")
            return {'CANCELLED'}
        context.window_manager.progress_update(int(100 * fraction))
        context.workspace.status_text_set(f"{self.bl_label}: {message} (Esc to cancel)")
        return {'RUNNING_MODAL'}

    def _finish(self, context):
        wm = context.window_manager
        wm.event_timer_remove(self._timer)
        wm.progress_end()
        context.workspace.status_text_set(None)
        JobOperator._running = False
