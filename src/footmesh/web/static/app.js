// footmesh web app: upload with progress, then the result (tables, overlay, downloads, 3D view).
// The 3D viewer is loaded only when needed and only where WebGL works; everything else works without it.

const $ = (id) => document.getElementById(id);

const LABELS = {
  stick_length: 'Foot length (heel to longest toe)',
  ball_width: 'Ball width',
  heel_width: 'Heel width',
  toe_height: 'Big-toe height',
  arch_height: 'Arch height',
  instep_height: 'Instep height',
  ball_girth: 'Ball girth',
  instep_girth: 'Instep girth',
};
const SCALE_SOURCES = {
  depth: 'the depth map',
  // the reference objects' names come from footmesh.references, through the page
  ...JSON.parse(document.body.dataset.scaleSources || '{}'),
  declared: 'the declared camera distance',
  none: 'none: no scale reference was found, so there are no millimetre figures and no sizes',
};
const SIZE_SYSTEMS = {
  mondopoint: 'Mondopoint (foot length/width, mm)',
  eu: 'EU (Paris points)',
  uk: 'UK',
  uk_child: 'UK children',
  us_men: 'US men',
  us_women: 'US women',
  us_child: 'US children',
};

const body = document.body;
const maxUploadBytes = Number(body.dataset.maxUploadBytes);
const viewerConfig = JSON.parse(body.dataset.viewer || '{}');
let viewer = null; // the current 3D view, disposed when a new result comes
let timer = null;

function setStatus(text, progress) {
  $('status-text').textContent = text;
  const bar = $('progress');
  if (progress === undefined) {
    bar.hidden = true;
  } else {
    bar.hidden = false;
    if (progress === null) bar.removeAttribute('value'); // indeterminate: measuring
    else bar.value = progress;
  }
}

function showError(message) {
  const box = $('error');
  box.textContent = message;
  box.hidden = false;
  box.focus();
}

function busy(on) {
  $('submit').disabled = on;
  $('form').setAttribute('aria-busy', on ? 'true' : 'false');
  if (!on && timer) {
    clearInterval(timer);
    timer = null;
  }
}

function errorText(status, text) {
  let detail = '';
  try {
    const data = JSON.parse(text);
    detail = typeof data.detail === 'string' ? data.detail : JSON.stringify(data.detail);
  } catch {
    detail = text && text.length < 300 ? text : '';
  }
  const what = {
    400: 'The file could not be read',
    413: 'Too large',
    415: 'Not a supported file type',
    422: 'No measurement',
    503: 'The server is busy',
    504: 'Took too long',
  }[status] || `Error ${status}`;
  return detail ? `${what}: ${detail}` : what;
}

function submit(event) {
  event.preventDefault();
  const form = $('form');
  const data = new FormData(form);
  for (const key of ['depth', 'intrinsics']) {
    const file = data.get(key);
    if (file instanceof File && file.size === 0 && !file.name) data.delete(key);
  }
  const photo = data.get('photo');
  $('error').hidden = true;
  if (!(photo instanceof File) || (!photo.name && photo.size === 0)) {
    showError('Choose a photo first.');
    $('photo').focus();
    return;
  }
  let total = 0;
  for (const value of data.values()) total += value instanceof File ? value.size : 0;
  if (total > maxUploadBytes) {
    showError(`Too large: the files add up to ${(total / 1048576).toFixed(1)} MB; ` +
              `the limit is ${(maxUploadBytes / 1048576).toFixed(0)} MB.`);
    return;
  }
  busy(true);
  $('results').hidden = true; // an earlier result must not pass for this photo's
  setStatus('Uploading…', 0);
  const xhr = new XMLHttpRequest();
  xhr.open('POST', '/api/measure');
  xhr.upload.addEventListener('progress', (e) => {
    if (e.lengthComputable) setStatus(`Uploading… ${Math.round((100 * e.loaded) / e.total)} %`, (100 * e.loaded) / e.total);
  });
  xhr.upload.addEventListener('load', () => {
    const start = Date.now();
    setStatus('Measuring…', null);
    timer = setInterval(() => setStatus(`Measuring… ${Math.round((Date.now() - start) / 1000)} s`, null), 1000);
  });
  xhr.addEventListener('load', () => {
    busy(false);
    if (xhr.status === 200) {
      let result;
      try {
        result = JSON.parse(xhr.responseText);
      } catch {
        setStatus('');
        showError('The server sent an answer that is not JSON.');
        return;
      }
      setStatus('Done.');
      showResult(result, xhr.getResponseHeader('X-Result-Id'));
    } else {
      setStatus('');
      showError(errorText(xhr.status, xhr.responseText));
    }
  });
  xhr.addEventListener('error', () => {
    busy(false);
    setStatus('');
    showError('The server could not be reached. Is it still running?');
  });
  xhr.send(data);
}

function fmt(value, digits = 1) {
  return typeof value === 'number' && Number.isFinite(value) ? value.toFixed(digits) : '—';
}

function cell(row, text, cls) {
  const td = document.createElement(row.children.length === 0 ? 'th' : 'td');
  if (row.children.length === 0) td.scope = 'row';
  td.textContent = text;
  if (cls) td.className = cls;
  row.appendChild(td);
}

function fillTable(id, rows) {
  const tbody = $(id).querySelector('tbody');
  tbody.replaceChildren();
  for (const values of rows) {
    const tr = document.createElement('tr');
    values.forEach((v, i) => cell(tr, v, i > 0 && (id !== 'sizes' || i > 1) ? 'num' : ''));
    tbody.appendChild(tr);
  }
}

function showResult(result, rid) {
  const files = result.files || {};
  const url = (name) => `/api/results/${encodeURIComponent(rid)}/${encodeURIComponent(name)}`;

  $('scale').textContent = `Scale from ${SCALE_SOURCES[result.scale_source] || result.scale_source}` +
    (result.side ? ` · ${result.side} foot` : '');
  const messages = $('messages');
  messages.replaceChildren();
  for (const m of result.messages || []) {
    const li = document.createElement('li');
    li.textContent = m;
    messages.appendChild(li);
  }

  const m = result.measurements || {};
  fillTable('measurements', Object.keys(LABELS).filter((k) => k in m).map((k) => [
    LABELS[k],
    m[k].value_mm == null ? '—' : `${fmt(m[k].value_mm)} mm`,
    m[k].uncertainty_mm == null ? '—' : `± ${fmt(m[k].uncertainty_mm)} mm`,
  ]));

  const sizes = result.sizes || {};
  const sizeRows = Object.keys(SIZE_SYSTEMS).filter((k) => sizes[k] && sizes[k].label).map((k) => [
    SIZE_SYSTEMS[k], sizes[k].label, fmt(sizes[k].exact, 2),
  ]);
  fillTable('sizes', sizeRows.length ? sizeRows : [['—', 'no sizes without a scale', '']]);
  fillTable('ratios', Object.entries(result.ratios || {}).map(([k, v]) => [k.replace('/', ' / '), fmt(v, 3)]));

  const links = { 'download-obj': files.mesh_obj, 'download-glb': files.mesh_glb, 'download-json': files.result_json };
  for (const [id, name] of Object.entries(links)) {
    const a = $(id);
    a.hidden = !name;
    if (name) a.href = url(name);
  }
  const overlay = $('overlay');
  overlay.closest('figure').hidden = !files.overlay_png;
  if (files.overlay_png) overlay.src = url(files.overlay_png);

  $('results').hidden = false;
  $('results').dataset.resultId = rid;
  $('results-heading').focus();
  show3d(files.mesh_glb ? url(files.mesh_glb) : null, result.joints3d_mm);
}

function webglAvailable() {
  try {
    const canvas = document.createElement('canvas');
    return Boolean(window.WebGL2RenderingContext && canvas.getContext('webgl2'))
      || Boolean(window.WebGLRenderingContext && canvas.getContext('webgl'));
  } catch {
    return false;
  }
}

async function show3d(meshUrl, joints) {
  const box = $('viewer');
  const fallback = $('viewer-fallback');
  if (viewer) viewer.dispose();
  viewer = null;
  box.replaceChildren();
  box.dataset.state = 'loading';
  fallback.hidden = true;
  $('viewer-reset').hidden = true;
  const noView = (why) => {
    box.hidden = true;
    box.dataset.state = 'unavailable';
    $('viewer-help').hidden = true;
    fallback.hidden = false;
    fallback.textContent = `${why} The measurements above do not need it; the mesh can be downloaded below.`;
  };
  if (!meshUrl) return noView('This result has no mesh to show.');
  if (!webglAvailable()) return noView('The 3D view needs WebGL, which this browser does not offer.');
  box.hidden = false;
  $('viewer-help').hidden = false;
  try {
    const { showFoot } = await import('./viewer.js');
    viewer = await showFoot(box, meshUrl, joints, viewerConfig.parents || []);
    $('viewer-reset').hidden = false;
    box.dataset.state = 'ready';
  } catch (err) {
    console.error(err);
    noView('The 3D view could not be shown.');
  }
}

$('form').addEventListener('submit', submit);
$('viewer-reset').addEventListener('click', () => viewer && viewer.reset());
