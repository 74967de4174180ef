// ubitrack view: the page's script. Every second it fetches /status.json, /series.json and
// /flow.svg from the view that served the page and redraws. Written by hand, no library: it
// fills a few tables and draws polylines, which the DOM does in a few lines, and the page
// must need no network beyond the view (no CDN). Everything it shows comes from the network
// (the agent's status, names of frames and workers): it is written as text (textContent) or
// as numbers into SVG attributes, never parsed as markup.
"use strict";

const EVERY_MS = 1000;
const SVG = "http://www.w3.org/2000/svg";
const SPARK = { width: 180, height: 28, pad: 2 };

function element(tag, text, className) {
  const node = document.createElement(tag);
  if (text !== undefined && text !== null) node.textContent = String(text);
  if (className) node.className = className;
  return node;
}

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

// A sparkline of values against time (seconds before now), from zero to the largest value;
// a period without a value (null) breaks the line.
function sparkline(times, values, unit) {
  const svg = document.createElementNS(SVG, "svg");
  svg.setAttribute("class", "spark");
  svg.setAttribute("width", SPARK.width);
  svg.setAttribute("height", SPARK.height);
  const points = list(times).map((t, i) => [t, list(values)[i]]).filter(([t]) => finite(t));
  const known = points.filter(([, v]) => finite(v)).map(([, v]) => v);
  if (points.length === 0 || known.length === 0) return svg;
  const span = Math.max(-points[0][0], 1e-9);
  const top = Math.max(...known, 1e-9);
  const x = (t) => SPARK.pad + (SPARK.width - 2 * SPARK.pad) * (1 + t / span);
  const y = (v) => SPARK.height - SPARK.pad - (SPARK.height - 2 * SPARK.pad) * (v / top);
  let run = [];
  const flush = () => {
    if (run.length > 0) {
      const line = document.createElementNS(SVG, "polyline");
      line.setAttribute("points", run.join(" "));
      line.setAttribute("fill", "none");
      line.setAttribute("stroke", "#2a6fb0");
      line.setAttribute("stroke-width", "1.5");
      svg.appendChild(line);
    }
    run = [];
  };
  for (const [t, v] of points) {
    if (finite(v)) run.push(`${x(t).toFixed(1)},${y(v).toFixed(1)}`);
    else flush();
  }
  flush();
  const title = document.createElementNS(SVG, "title");
  title.textContent = `0 to ${top.toFixed(2)} ${unit} over the last ${span.toFixed(0)} s`;
  svg.appendChild(title);
  return svg;
}

// A cell with the sparkline of one series and its latest value (the rate of the last
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

let flowURL = null;

async function drawFlow() {
  const image = document.getElementById("flow");
  const problem = document.getElementById("flow-problem");
  const dot = document.getElementById("flow-dot");
  const response = await fetch("/flow.svg", { cache: "no-store" });
  if (response.ok) {
    const url = URL.createObjectURL(await response.blob());
    image.src = url;
    if (flowURL) URL.revokeObjectURL(flowURL);
    flowURL = url;
    image.hidden = false;
    problem.hidden = dot.hidden = true;
    return;
  }
  image.hidden = true;
  problem.textContent = (await response.text()).trim();
  problem.hidden = false;
  const source = await fetch("/flow.dot", { cache: "no-store" });
  dot.textContent = source.ok ? await source.text() : "";
  dot.hidden = !source.ok;
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

tick();
setInterval(tick, EVERY_MS);
