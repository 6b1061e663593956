// The FlowClip editor: wires the hub, the viewport and the panels, then opens
// a scene: ?scene=NAME (empty: none), ?session=ID attaches to an existing
// session, default drop2d (or the first scene listed).
import './styles.css';
import * as flatbuffers from 'flatbuffers';
import { Envelope, Frame } from '@wire';
import { Editor } from './core/Editor';
import { Viewport } from './viewport/Viewport';
import { Toolbar } from './ui/Toolbar';
import { StatusBar } from './ui/StatusBar';
import { LayerPanel, StatsOverlay } from './ui/Overlays';
import { Messages } from './ui/Messages';
import { Timeline } from './ui/Timeline';
import { installKeyboard } from './ui/Keyboard';
import { TemplateLibrary } from './ui/TemplateLibrary';
import { Outliner } from './ui/Outliner';
import { Inspector } from './ui/Inspector';
import { el } from './ui/dom';
import { SetInstanceTransformCommand } from './commands/SetInstanceTransformCommand';
import { SetInstanceValuesCommand } from './commands/SetInstanceValuesCommand';
import { AddInstanceCommand } from './commands/AddInstanceCommand';
import * as track from './core/TransformTrack';
import { ExportDialog } from './ui/ExportDialog';
import { RenderDialog } from './ui/RenderDialog';
import { JobsPanel } from './ui/JobsPanel';

const DEFAULT_SCENE = 'drop2d';

const editor = new Editor();
const app = document.getElementById('app')!;
const toolbar = new Toolbar(editor);
const viewportDom = el('main', { className: 'viewport', testid: 'viewport' });
const messages = new Messages(editor);
const statusBar = new StatusBar(editor);
// Layout (styles.css #app grid): toolbar on top; the template library, the
// layer toggles, the simulation stats and the render jobs on the left; the viewport; the outliner and inspector on the right; the timeline
// under the viewport; the status bar at the bottom.
const leftPanel = el('aside', { className: 'sidebar left', testid: 'left-panel' });
const rightPanel = el('aside', { className: 'sidebar right', testid: 'right-panel' });
const timelineDom = el('section', { className: 'timeline-area', testid: 'timeline-area' });
toolbar.dom.classList.add('area-toolbar');
statusBar.dom.classList.add('area-status');
app.append(toolbar.dom, leftPanel, viewportDom, rightPanel, timelineDom, statusBar.dom);
viewportDom.append(messages.dom);
app.append(new ExportDialog(editor).dom, new RenderDialog(editor).dom);
leftPanel.append(new TemplateLibrary(editor).dom, new LayerPanel(editor).dom, new StatsOverlay(editor).dom, new JobsPanel(editor).dom);
rightPanel.append(new Outliner(editor).dom, new Inspector(editor).dom);
timelineDom.append(new Timeline(editor).dom);
const viewport = new Viewport(viewportDom, editor);
installKeyboard(editor);

// For debugging from the console, tests and the browser benchmark
// (scripts/bench-browser.mjs decodes fetched frames with `wire`); never used
// by the editor itself.
(window as unknown as { flowclip: unknown }).flowclip = {
  editor,
  viewport,
  commands: { SetInstanceTransformCommand, SetInstanceValuesCommand, AddInstanceCommand },
  track,
  wire: { ByteBuffer: flatbuffers.ByteBuffer, Envelope, Frame },
};

// Sessions this editor created are deleted when the page goes away.
window.addEventListener('pagehide', () => {
  const s = editor.session;
  if (s?.owned) {
    const headers: Record<string, string> = editor.api.token ? { Authorization: `Bearer ${editor.api.token}` } : {};
    void fetch(`/api/sessions/${encodeURIComponent(s.id)}`, { method: 'DELETE', keepalive: true, headers }).catch(() => undefined);
  }
});

async function start() {
  const params = new URLSearchParams(location.search);
  void editor.loadTemplates();
  void editor.recipes.load();
  void editor.loadPresets();
  void editor.loadRenderAvailability();
  const scenes = await editor.loadScenes();
  const session = params.get('session');
  if (session) {
    await editor.attachSession(session);
    return;
  }
  const wanted = params.has('scene') ? params.get('scene')! : DEFAULT_SCENE;
  if (wanted === '') return;
  const usable = scenes.filter((s) => !s.error);
  const scene = usable.find((s) => s.name === wanted) ?? (params.has('scene') ? undefined : usable[0]);
  if (scene) await editor.openScene(scene.name);
  else editor.message('warning', `no scene ${wanted} on the server`);
}

void start();
