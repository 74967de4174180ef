// ubitrack view: the page's script. Every second it fetches /status.json, /series.json and
// /flow.json from the view that served the page and redraws: tables, sparklines with axes,
// and the data flow laid out by dagre (bundled, /vendor/dagre/; the page needs no network
// beyond the view, no CDN), or Graphviz's picture (/flow.svg) when chosen. Everything it shows
// comes from the network (the agent's status, names of frames and workers): it is written as
// text (textContent) or as numbers into SVG attributes, never parsed as markup.
import { element } from "/dom.js";


const EVERY_MS = 1000;
const SVG = "http://www.w3.org/2000/svg";
const SPARK = { width: 230, height: 58, left: 44 };

function object(value) {
  return value !== null && typeof value === "object" && !Array.isArray(value) ? value : {};
}

function list(value) {
  return Array.isArray(value) ? value : [];
}

function finite(value) {
  return typeof value === "number" && Number.isFinite(value);
}

async function fetchJSON(path) {
  const response = await fetch(path, { cache: "no-store" });
  let body = null;
  try {
    body = await response.json();
  } catch (error) {
    body = null;
  }
  return { ok: response.ok, body: object(body) };
}

// A sparkline of values against time (seconds before now), from zero to the largest value,
// with its axes: the value scale on the left (0 and the top, in the unit), the time below
// (the oldest point's age and "now"); a period without a value (null) breaks the line.
function sparkline(times, values, unit) {
  const svg = svgElement("svg", { class: "spark", width: SPARK.width, height: SPARK.height });
  const points = list(times).map((t, i) => [t, list(values)[i]]).filter(([t]) => finite(t));
  const known = points.filter(([, v]) => finite(v)).map(([, v]) => v);
  if (points.length === 0 || known.length === 0) return svg;
  const span = Math.max(-points[0][0], 1e-9);
  const top = niceCeiling(Math.max(...known));
  const plot = { left: SPARK.left, right: SPARK.width - 4, top: 4, bottom: SPARK.height - 14 };
  const x = (t) => plot.left + (plot.right - plot.left) * (1 + t / span);
  const y = (v) => plot.bottom - (plot.bottom - plot.top) * (v / top);
  svg.append(
    svgElement("path", {
      class: "axis",
      d: `M${plot.left},${plot.top} V${plot.bottom} H${plot.right}`,
    }),
    svgText(plot.left - 3, plot.top + 7, `${formatted(top)} ${unit}`, "end"),
    svgText(plot.left - 3, plot.bottom, `0`, "end"),
    svgText(plot.left, SPARK.height - 2, `-${span.toFixed(0)} s`, "start"),
    svgText(plot.right, SPARK.height - 2, "now", "end"),
  );
  let run = [];
  const flush = () => {
    if (run.length > 0) svg.append(svgElement("polyline", { class: "line", points: run.join(" ") }));
    run = [];
  };
  for (const [t, v] of points) {
    if (finite(v)) run.push(`${x(t).toFixed(1)},${y(Math.min(v, top)).toFixed(1)}`);
    else flush();
  }
  flush();
  const title = svgElement("title");
  title.textContent = `0 to ${formatted(top)} ${unit} over the last ${span.toFixed(0)} s`;
  svg.appendChild(title);
  return svg;
}

// The smallest of 1, 2, 5 times a power of ten at or above value: a round top for an axis.
function niceCeiling(value) {
  const scale = 10 ** Math.floor(Math.log10(Math.max(value, 1e-9)));
  return [1, 2, 5, 10].map((step) => step * scale).find((top) => top >= value);
}

function formatted(value) {
  return value >= 10 ? value.toFixed(0) : String(Number(value.toPrecision(2)));
}

function svgElement(tag, attributes) {
  const node = document.createElementNS(SVG, tag);
  for (const [name, value] of Object.entries(attributes || {})) node.setAttribute(name, value);
  return node;
}

function svgText(x, y, text, anchor, className) {
  const node = svgElement("text", { x, y, "text-anchor": anchor, class: className || "tick" });
  node.textContent = text;
  return node;
}

// A cell with the sparkline of one series and its current value (the rate of the last
// period; for latency and error the last period's that had one), or why there is none.
function sparkCell(series, field, unit, digits, absent) {
  const cell = element("td");
  if (!series) {
    cell.appendChild(element("span", absent || "–", "value none"));
    return cell;
  }
  const values = list(series[field]);
  const known = field === "rate_hz" ? values.slice(-1) : values.filter(finite);
  const latest = known.length > 0 ? known[known.length - 1] : null;
  cell.appendChild(sparkline(series.t_s, values, unit));
  const shown = finite(latest) ? `${latest.toFixed(digits)} ${unit}` : absent || "–";
  cell.appendChild(element("span", shown, finite(latest) ? "value" : "value none"));
  return cell;
}

function fillRows(table, rows) {
  document.querySelector(`#${table} tbody`).replaceChildren(...rows);
}

function drawAgent(status, problem) {
  const agent = object(status.agent);
  const text = problem
    ? "no status from the agent"
    : `agent ${agent.id} (${agent.role}) on ${status.key_prefix}` +
      (list(agent.standby).length ? `; standing by: ${list(agent.standby).join(", ")}` : "");
  document.getElementById("agent").textContent = text;
  const banner = document.getElementById("problem");
  banner.textContent = problem || "";
  banner.hidden = !problem;
}

function drawHosts(status) {
  const info = object(status.host_info);
  const names = [...new Set([...list(status.hosts), ...Object.keys(info)])].sort();
  fillRows(
    "hosts",
    names.map((name) => {
      const host = object(info[name]);
      const row = element("tr");
      row.append(
        element("td", name),
        element("td", finite(host.capacity) ? host.capacity : "–"),
        element("td", finite(host.cpu_load) ? host.cpu_load.toFixed(2) : "–"),
        element("td", list(host.labels).join(", ")),
      );
      return row;
    }),
  );
}

function drawComponents(status) {
  const components = object(status.components);
  fillRows(
    "components",
    Object.keys(components)
      .sort()
      .map((instance) => {
        const component = object(components[instance]);
        const row = element("tr", null, component.alive ? "" : "starting");
        row.dataset.instance = instance;
        row.append(
          element("td", component.pattern || component.service),
          element("td", instance),
          element("td", component.host || "–"),
          element("td", component.container || "–"),
          element("td", component.alive ? "alive" : "starting"),
          element("td", finite(component.rate_hz) ? `${component.rate_hz.toFixed(0)} Hz` : "–"),
        );
        return row;
      }),
  );
}

// A row per queried relation (/series.json's rows): its applications, and its sparklines
// or why it is unsolved.
function drawRelations(rows) {
  fillRows(
    "relations",
    Object.keys(rows)
      .sort()
      .map((name) => {
        const entry = object(rows[name]);
        const series = entry.series ? object(entry.series) : null;
        const row = element("tr");
        row.dataset.relation = name;
        row.append(element("td", name), element("td", list(entry.applications).join(", ")));
        if (typeof entry.unsolved === "string") {
          const cell = element("td", `unsolved: ${entry.unsolved}`, "problem");
          cell.colSpan = 3;
          row.append(cell);
          return row;
        }
        const noTruth = series && series.truth === false ? "no ground truth" : undefined;
        const noLatency = series && series.kind !== "dynamic" ? "static" : undefined;
        row.append(
          sparkCell(series, "rate_hz", "Hz", 1),
          sparkCell(series, "latency_ms", "ms", 1, noLatency),
          sparkCell(series, "error_mm", "mm", 2, noTruth),
        );
        return row;
      }),
  );
}

function drawUnsolved(rows, known) {
  const items = Object.keys(rows)
    .filter((name) => typeof object(rows[name]).unsolved === "string")
    .sort()
    .map((name) => element("li", `${name}: ${rows[name].unsolved}`));
  if (items.length === 0) items.push(element("li", known ? "none" : "–", "none"));
  document.getElementById("unsolved").replaceChildren(...items);
}

function drawCounters(series) {
  const counters = object(series.counters);
  const text = Object.keys(counters)
    .sort()
    .map((name) => `${name} ${counters[name]}`)
    .join(", ");
  document.getElementById("view-counters").textContent = text ? `view: ${text}` : "";
}

// The data flow (/flow.json: nodes, wires, groups), laid out by dagre (the bundled layered
// layout, left to right as the paper's figure 6) and drawn as SVG: providers as sources,
// components as boxes inside their container's dashed box, applications as sinks; static
// wires dashed, starting components grey. Laid out again only when the flow changed.
const FLOW = { font: "12px system-ui, sans-serif", line: 15, pad: 8, label: 11 };
const measure = document.createElement("canvas").getContext("2d");

function textWidth(text, font) {
  measure.font = font || FLOW.font;
  return measure.measureText(text).width;
}

function layoutFlow(flow) {
  const graph = new dagre.graphlib.Graph({ compound: true, multigraph: true });
  graph.setGraph({ rankdir: "LR", nodesep: 18, ranksep: 60, edgesep: 12, marginx: 8, marginy: 22 });
  graph.setDefaultEdgeLabel(() => ({}));
  for (const group of list(flow.groups)) graph.setNode(`group ${group.id}`, { group });
  for (const node of list(flow.nodes)) {
    const lines = list(node.lines).map(String);
    const width = Math.max(...lines.map((line) => textWidth(line)), 20) + 2 * FLOW.pad;
    const extra = node.kind === "provider" || node.kind === "application" ? 14 : 0;
    graph.setNode(node.id, { node, lines, width: width + extra, height: lines.length * FLOW.line + 10 });
    if (node.group !== null && node.group !== undefined) graph.setParent(node.id, `group ${node.group}`);
  }
  list(flow.wires).forEach((wire, index) => {
    if (!graph.hasNode(wire.from) || !graph.hasNode(wire.to)) return;
    const label = String(wire.label);
    graph.setEdge(
      wire.from,
      wire.to,
      { wire, label, width: textWidth(label, `${FLOW.label}px system-ui, sans-serif`) + 4, height: 14, labelpos: "c" },
      `wire ${index}`,
    );
  });
  dagre.layout(graph);
  return graph;
}

// The outline of a node of each kind, centred on (x, y): figure 6's shapes.
function outline(kind, x, y, w, h) {
  const [l, r, t, b] = [x - w / 2, x + w / 2, y - h / 2, y + h / 2];
  if (kind === "provider") return `M${l},${t} H${r - 10} L${r},${y} L${r - 10},${b} H${l} Z`;
  if (kind === "application") return `M${l},${t} H${r} V${b} H${l} L${l + 10},${y} Z`;
  return `M${l + 4},${t} H${r - 4} Q${r},${t} ${r},${t + 4} V${b - 4} Q${r},${b} ${r - 4},${b} H${l + 4} Q${l},${b} ${l},${b - 4} V${t + 4} Q${l},${t} ${l + 4},${t} Z`;
}

function drawFlowGraph(svg, graph) {
  const defs = svgElement("defs");
  const marker = svgElement("marker", { id: "arrow", viewBox: "0 0 10 10", refX: 10, refY: 5, markerWidth: 7, markerHeight: 7, orient: "auto" });
  marker.append(svgElement("path", { d: "M0,0 L10,5 L0,10 Z", class: "arrowhead" }));
  defs.append(marker);
  const layers = ["groups", "wires", "nodes", "labels"].map((name) => svgElement("g", { class: name }));
  svg.replaceChildren(defs, ...layers);
  const [groups, wires, nodes, labels] = layers;
  for (const id of graph.nodes()) {
    const { x, y, width, height, node, lines, group } = graph.node(id);
    if (group) {
      groups.append(svgElement("rect", { class: "group", x: x - width / 2, y: y - height / 2 - 16, width, height: height + 16, rx: 6 }));
      groups.append(svgText(x - width / 2 + 6, y - height / 2 - 4, list(group.lines).join(", "), "start", "group-label"));
      continue;
    }
    const alive = node.alive !== false;
    const shape = svgElement("g", { class: `node ${node.kind}${alive ? "" : " starting"}` });
    shape.dataset.id = id;
    if (node.kind !== "key") shape.append(svgElement("path", { d: outline(node.kind, x, y, width, height) }));
    lines.forEach((line, i) => {
      const baseline = y - ((lines.length - 1) * FLOW.line) / 2 + i * FLOW.line + 4;
      shape.append(svgText(x, baseline, line, "middle", i === 0 ? "name" : "detail"));
    });
    nodes.append(shape);
  }
  for (const edge of graph.edges()) {
    const { points, wire, label, x, y } = graph.edge(edge);
    const d = points.map((p, i) => `${i ? "L" : "M"}${p.x.toFixed(1)},${p.y.toFixed(1)}`).join(" ");
    wires.append(svgElement("path", { class: wire.static ? "wire static" : "wire", d, "marker-end": "url(#arrow)" }));
    if (label) labels.append(svgText(x, y + 4, label, "middle", "wire-label"));
  }
  const box = svg.getBBox(); // what was drawn: dagre's size also counts its layout's margins
  const view = [box.x - 4, box.y - 4, box.width + 8, box.height + 8].map(Math.round);
  svg.setAttribute("viewBox", view.join(" "));
  svg.setAttribute("width", view[2]);
  svg.setAttribute("height", view[3]);
}

// The legend: one swatch per kind of node and wire the flow draws.
function drawLegend() {
  const svg = document.getElementById("flow-legend");
  const entries = [
    ["provider", "provider (a source of measured edges)"],
    ["component", "component (one step of a pattern)"],
    ["starting", "component starting"],
    ["application", "application (a queried relation)"],
    ["group", "container: components run in one process"],
    ["wire", "wire: type, rate, latency at its consumer"],
    ["static", "static wire (a calibration, sent when it changes)"],
  ];
  svg.setAttribute("width", 760);
  svg.setAttribute("height", 20 * Math.ceil(entries.length / 2) + 4);
  svg.replaceChildren(
    ...entries.map(([kind, text], i) => {
      const [x, y] = [(i % 2) * 380 + 2, Math.floor(i / 2) * 20 + 12];
      const item = svgElement("g", { class: "legend-item" });
      if (kind === "wire" || kind === "static") {
        item.append(svgElement("path", { class: kind === "static" ? "wire static" : "wire", d: `M${x},${y} H${x + 40}` }));
      } else if (kind === "group") {
        item.append(svgElement("rect", { class: "group", x, y: y - 7, width: 40, height: 14, rx: 4 }));
      } else {
        const shape = svgElement("g", { class: `node ${kind === "starting" ? "component starting" : kind}` });
        shape.append(svgElement("path", { d: outline(kind === "starting" ? "component" : kind, x + 20, y, 40, 14) }));
        item.append(shape);
      }
      item.append(svgText(x + 48, y + 4, text, "start", "legend-text"));
      return item;
    }),
  );
}

let flowShown = "";
let flowURL = null;

async function drawFlow() {
  const svg = document.getElementById("flow");
  const picture = document.getElementById("flow-picture");
  const problem = document.getElementById("flow-problem");
  problem.hidden = true;
  if (document.getElementById("flow-engine").value === "graphviz") {
    const response = await fetch("/flow.svg", { cache: "no-store" });
    if (response.ok) {
      const url = URL.createObjectURL(await response.blob());
      picture.src = url;
      if (flowURL) URL.revokeObjectURL(flowURL);
      flowURL = url;
      picture.hidden = false;
      svg.toggleAttribute("hidden", true); // an SVG element has no .hidden property
      return;
    }
    problem.textContent = `${(await response.text()).trim()}; drawn in the browser instead`;
    problem.hidden = false;
  }
  picture.hidden = true;
  svg.toggleAttribute("hidden", false);
  const response = await fetch("/flow.json", { cache: "no-store" });
  const text = await response.text();
  if (!response.ok) {
    let why = text;
    try {
      why = String(object(JSON.parse(text)).error);
    } catch (error) {
      why = text;
    }
    problem.textContent = `no data flow: ${why}`;
    problem.hidden = false;
    svg.replaceChildren();
    flowShown = "";
    return;
  }
  if (text === flowShown) return;
  drawFlowGraph(svg, layoutFlow(object(JSON.parse(text))));
  flowShown = text;
}

async function redraw() {
  let status, series;
  try {
    [status, series] = await Promise.all([fetchJSON("/status.json"), fetchJSON("/series.json")]);
  } catch (error) {
    drawAgent({}, `the view does not answer: ${error}`);
    return;
  }
  const problem = status.ok ? null : String(status.body.error || "no agent answers");
  drawAgent(status.body, problem);
  const shown = status.ok ? status.body : {};
  drawHosts(shown);
  drawComponents(shown);
  const rows = object(series.body.relations);
  drawRelations(rows);
  drawUnsolved(rows, status.ok);
  drawCounters(series.body);
  await drawFlow();
  document.getElementById("updated").textContent = `updated ${new Date().toLocaleTimeString()}`;
}

let busy = false;

async function tick() {
  if (busy) return;
  busy = true;
  try {
    await redraw();
  } catch (error) {
    drawAgent({}, `the view does not answer: ${error}`);
  } finally {
    busy = false;
  }
}

// The drawing engine: the select, or the page's address (/#engine=graphviz).
const engine = document.getElementById("flow-engine");
if (new URLSearchParams(location.hash.slice(1)).get("engine") === "graphviz") engine.value = "graphviz";
engine.addEventListener("change", () => {
  location.hash = `engine=${engine.value}`;
  flowShown = "";
});
drawLegend();
tick();
setInterval(tick, EVERY_MS);
