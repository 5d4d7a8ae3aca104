// arvcas front explore: the page's script (arvcas/experiments/explore.py writes the data it reads).
// Front plot: every front, its knee and its default gains, on two of the study's objectives (three or four:
// chosen with the selectors above the plot, or #x=NAME&y=NAME in the address; the others in the hover);
// hover: a member's objectives, metrics and gains; click: its time response (tracking errors of every
// selected member, thrust of the last one) and its details.
(function () {
  "use strict";
  var status = document.getElementById("status");
  window.addEventListener("error", function (e) { status.textContent = "error: " + e.message; });

  var doc = JSON.parse(document.getElementById("data").textContent);
  var fronts = doc.fronts;
  var OBJ = doc.objectives;  // the columns of every front's F: name, label (axis title), unit, description, log
  var DASH = ["solid", "dash", "dot", "dashdot"];
  var MAX_SELECTED = 4;
  var THRUST_COLORS = ["#0072B2", "#D55E00", "#009E73", "#CC79A7", "#E69F00", "#56B4E9", "#000000", "#F0E442",
                       "#999999", "#882255", "#44AA99", "#117733"];

  function fmt(v, d) {
    if (v === null || v === undefined) { return "n/a"; }
    return Number(v).toPrecision(d || 4).replace(/\.?0+(e|$)/, "$1");
  }

  // every text a user controls (names, labels, descriptions, paths) goes through esc before it reaches HTML or
  // a plotly label (plotly reads the same entities back as text)
  function esc(s) {
    return String(s).replace(/[&<>"]/g, function (c) {
      return { "&": "&amp;", "<": "&lt;", ">": "&gt;", "\"": "&quot;" }[c];
    });
  }

  // 16-bit codes per column (value = lo + step * code; 65535: missing) -> one array per column
  function unpack(p, width) {
    var bin = atob(p.q);
    var n = bin.length / 2 / width;
    var view = new DataView(new ArrayBuffer(bin.length));
    for (var b = 0; b < bin.length; b++) { view.setUint8(b, bin.charCodeAt(b)); }
    var cols = [];
    for (var j = 0; j < width; j++) {
      var col = new Array(n);
      for (var i = 0; i < n; i++) {
        var code = view.getUint16(2 * (i * width + j), true);
        col[i] = code === 65535 ? null : p.lo[j] + p.step[j] * code;
      }
      cols.push(col);
    }
    return cols;
  }

  var cache = {};
  function trace(fi, key) {
    var id = fi + "/" + key;
    if (!(id in cache)) {
      var tr = fronts[fi].traces[key];
      cache[id] = tr ? { e: unpack(tr.e, 6), u: unpack(tr.u, fronts[fi].thrusters.length), ok: tr.ok,
                         t_fail: tr.t_fail } : null;
    }
    return cache[id];
  }

  // gains grouped as a table: one row per gain column, one column per DOF ("x.c" -> row c, column x)
  function gainTable(names, values) {
    var rows = {}, order = [], scalars = [];
    names.forEach(function (n, i) {
      var parts = n.split(".");
      if (parts.length === 2 && doc.dofs.indexOf(parts[0]) >= 0) {
        if (!(parts[1] in rows)) { rows[parts[1]] = {}; order.push(parts[1]); }
        rows[parts[1]][parts[0]] = values[i];
      } else {
        scalars.push([n, values[i]]);
      }
    });
    return { rows: rows, order: order, scalars: scalars };
  }

  function memberInfo(fi, key) {
    var f = fronts[fi];
    if (key === "defaults") {
      return { name: f.label + ", " + doc.defaults_name, F: f.defaults.F, gains: f.defaults.gains,
               chat: f.defaults.chat, rmse: f.defaults.rmse };
    }
    var m = Number(key);
    return { name: f.label + ", member " + m + (m === f.knee ? " (knee)" : ""), F: f.F[m], gains: f.gains[m],
             chat: f.chat[m], rmse: f.rmse[m] };
  }

  // a member's objectives: "f_chat 1.2, f_rmse 3.4, f_energy 5.6e+04"
  function objectivesText(F, d) {
    return OBJ.map(function (o, j) { return "f_" + esc(o.name) + " " + fmt(F[j], d); }).join(", ");
  }

  function hoverText(fi, key) {
    var f = fronts[fi], info = memberInfo(fi, key);
    var lines = ["<b>" + esc(info.name) + "</b>",
                 objectivesText(info.F),
                 "DOF:  " + doc.dofs.join("  "),
                 "CHAT: " + (info.chat || []).map(function (v) { return fmt(v, 3); }).join("  "),
                 "RMSE: " + (info.rmse || []).map(function (v) { return fmt(v, 3); }).join("  "),
                 "gains (" + doc.dofs.join(", ") + "):"];
    var g = gainTable(f.gain_names, info.gains);
    g.order.forEach(function (r) {
      lines.push("  " + esc(r) + ": " + doc.dofs.map(function (d) { return fmt(g.rows[r][d], 3); }).join(", "));
    });
    g.scalars.forEach(function (s) { lines.push("  " + esc(s[0]) + ": " + fmt(s[1], 4)); });
    if (!f.traces[key]) { lines.push("<i>no stored time response</i>"); }
    return lines.join("<br>");
  }

  // ---- the front plot: objectives ix (x) and iy (y); with three or four objectives they are chosen --------
  var ix = 0, iy = 1;
  (function () {  // #x=NAME&y=NAME in the address: the first view's axes
    var names = OBJ.map(function (o) { return o.name; }), want = {};
    window.location.hash.replace(/^#/, "").split("&").forEach(function (kv) {
      var p = kv.split("=");
      if (p.length === 2) { want[p[0]] = names.indexOf(decodeURIComponent(p[1])); }
    });
    if (want.x >= 0) { ix = want.x; }
    if (want.y >= 0) { iy = want.y; }
    if (ix === iy) { iy = ix === 0 ? 1 : 0; }
  }());
  var LINES = OBJ.length === 2;  // two objectives: each front is a curve (members sorted by the first)

  var meta = [], selTrace;
  function frontTraces() {
    var out = [];
    meta = [];
    function xy(F) { return { x: F.map(function (p) { return p[ix]; }), y: F.map(function (p) { return p[iy]; }) }; }
    fronts.forEach(function (f, fi) {
      var pop = xy(f.population), mem = xy(f.F);
      out.push({ x: pop.x, y: pop.y, mode: "markers", type: "scatter",
                 marker: { color: f.color, size: 4, opacity: 0.2 }, hoverinfo: "skip", showlegend: false, legendgroup: f.path });
      meta.push(null);
      var keys = f.F.map(function (_, i) { return String(i); });
      out.push({ x: mem.x, y: mem.y, customdata: keys, text: keys.map(function (k) { return hoverText(fi, k); }),
                 hoverinfo: "text", mode: LINES ? "lines+markers" : "markers", type: "scatter", legendgroup: f.path,
                 name: esc(f.label) + ": front (" + f.F.length + "), HV " + fmt(f.hv),
                 line: { color: f.color, width: 1.2 }, marker: { color: f.color, size: 6 } });
      meta.push({ front: fi });
      if (f.knee >= 0) {
        out.push({ x: [f.F[f.knee][ix]], y: [f.F[f.knee][iy]], customdata: [String(f.knee)],
                   text: [hoverText(fi, String(f.knee))], hoverinfo: "text", mode: "markers", type: "scatter",
                   legendgroup: f.path, name: esc(f.label) + ": knee (member " + f.knee + ")",
                   marker: { color: f.color, size: 13, symbol: "diamond", line: { color: "#000", width: 1 } } });
        meta.push({ front: fi });
      }
      if (f.defaults.F[ix] !== null && f.defaults.F[iy] !== null) {
        out.push({ x: [f.defaults.F[ix]], y: [f.defaults.F[iy]], customdata: ["defaults"],
                   text: [hoverText(fi, "defaults")], hoverinfo: "text", mode: "markers", type: "scatter",
                   legendgroup: f.path, name: esc(f.label) + ": " + esc(doc.defaults_name) + ", same draw",
                   marker: { color: f.color, size: 16, symbol: "star", line: { color: "#000", width: 1 } } });
        meta.push({ front: fi });
      }
    });
    selTrace = out.length;
    var pts = selected.map(point);
    out.push({ x: pts.map(function (p) { return p[ix]; }), y: pts.map(function (p) { return p[iy]; }),
               mode: "markers", type: "scatter", hoverinfo: "skip", name: "selected",
               marker: { size: 18, color: "rgba(0,0,0,0)", line: { color: "#000", width: 2 } } });
    meta.push(null);
    return out;
  }

  function frontLayout() {
    function axis(o) {
      return { type: o.log ? "log" : "linear", title: { text: esc(o.label) }, gridcolor: "#e5e5e5" };
    }
    return {
      margin: { l: 55, r: 10, t: 30, b: 40 }, hovermode: "closest", hoverlabel: { align: "left", font: { size: 11 } },
      xaxis: axis(OBJ[ix]), yaxis: axis(OBJ[iy]),
      legend: { font: { size: 10 }, orientation: "h", y: -0.15, traceorder: "normal" },
      title: { text: "click members to see their time responses", font: { size: 12 } }, plot_bgcolor: "#fff"
    };
  }

  var frontDiv = document.getElementById("front");
  var selected = [];
  function drawFront() {
    Plotly.react(frontDiv, frontTraces(), frontLayout(), { displaylogo: false, responsive: true });
    frontDiv.setAttribute("data-axes", OBJ[ix].name + "," + OBJ[iy].name);
  }
  drawFront();

  // three or four objectives: a selector for each axis (changing one to the other's objective swaps them)
  if (OBJ.length > 2) {
    var axesDiv = document.getElementById("axes");
    var pick = {};
    ["x", "y"].forEach(function (a) {
      var sel = document.createElement("select");
      sel.id = "axis-" + a;
      OBJ.forEach(function (o, j) {
        var opt = document.createElement("option");
        opt.value = String(j);
        opt.textContent = o.label;
        sel.appendChild(opt);
      });
      var lab = document.createElement("label");
      lab.textContent = (a === "x" ? "x axis " : " y axis ");
      lab.appendChild(sel);
      axesDiv.appendChild(lab);
      pick[a] = sel;
      sel.onchange = function () {
        var j = Number(sel.value);
        if (a === "x") { if (j === iy) { iy = ix; } ix = j; } else { if (j === ix) { ix = iy; } iy = j; }
        pick.x.value = String(ix);
        pick.y.value = String(iy);
        drawFront();
      };
    });
    pick.x.value = String(ix);
    pick.y.value = String(iy);
    axesDiv.appendChild(document.createTextNode(" (the other objectives: in the hover and the details)"));
  }

  // ---- the selection ---------------------------------------------------------------------------------------

  function selectMember(fi, key, add) {
    if (!trace(fi, key)) {
      details(fi, key);
      return;
    }
    var id = fi + "/" + key;
    selected = selected.filter(function (s) { return s.id !== id; });
    if (!add) { selected = []; }
    selected.push({ id: id, front: fi, key: key });
    if (selected.length > MAX_SELECTED) { selected.shift(); }
    draw();
  }

  function point(s) {
    var info = memberInfo(s.front, s.key);
    return info.F;
  }

  function draw() {
    var pts = selected.map(point);
    Plotly.restyle(frontDiv, { x: [pts.map(function (p) { return p[ix]; })],
                               y: [pts.map(function (p) { return p[iy]; })] }, [selTrace]);
    response();
    var last = selected[selected.length - 1];
    details(last.front, last.key);
  }

  // six error panels (3 rows x 2 columns: x, y, z left; phi, theta, psi right) and one thrust panel below
  function response() {
    var traces = [], layout = {
      margin: { l: 60, r: 10, t: 40, b: 70 }, hovermode: "x unified", plot_bgcolor: "#fff",
      legend: { orientation: "h", y: -0.11, font: { size: 10 }, traceorder: "normal" }, annotations: [],
      title: { text: "Time response: tracking error e = eta - y1 of the selected members (the last " + MAX_SELECTED +
               " clicked), thrust of the last one; every " + fronts[0].k + " controller samples", font: { size: 12 } }
    };
    var rows = 4, gap = 0.05, h = (1 - gap * (rows - 1)) / rows;
    doc.dofs.forEach(function (d, i) {
      var col = i < 3 ? 0 : 1, row = i % 3;
      var ax = String(i + 1);
      var top = 1 - row * (h + gap);
      layout["xaxis" + ax] = { domain: col === 0 ? [0, 0.47] : [0.53, 1], anchor: "y" + ax, matches: "x7",
                               showticklabels: false, gridcolor: "#e5e5e5" };
      layout["yaxis" + ax] = { domain: [top - h, top], anchor: "x" + ax, gridcolor: "#e5e5e5",
                               title: { text: "e " + d + " (" + doc.dof_units[i] + ")", font: { size: 11 } },
                               zeroline: true, zerolinecolor: "#999" };
    });
    layout.xaxis7 = { domain: [0, 1], anchor: "y7", title: { text: "time (s)" }, gridcolor: "#e5e5e5" };
    layout.yaxis7 = { domain: [0, h], anchor: "x7", title: { text: "thrust (N)", font: { size: 11 } },
                      gridcolor: "#e5e5e5" };
    selected.forEach(function (s, n) {
      var f = fronts[s.front], tr = trace(s.front, s.key), name = memberInfo(s.front, s.key).name;
      doc.dofs.forEach(function (d, i) {
        traces.push({ x: f.t, y: tr.e[i], xaxis: "x" + (i + 1), yaxis: "y" + (i + 1), type: "scatter", mode: "lines",
                      line: { color: f.color, width: 1.2, dash: DASH[n % DASH.length] }, name: esc(name),
                      legendgroup: s.id, showlegend: i === 0, hovertemplate: "%{y:.4g}" });
      });
    });
    var last = selected[selected.length - 1], lf = fronts[last.front], lt = trace(last.front, last.key);
    lf.thrusters.forEach(function (tn, j) {
      traces.push({ x: lf.t, y: lt.u[j], xaxis: "x7", yaxis: "y7", type: "scatter", mode: "lines",
                    line: { color: THRUST_COLORS[j % THRUST_COLORS.length], width: 1 }, name: esc(tn),
                    legendgroup: "thrust", hovertemplate: "%{y:.4g}" });
    });
    if (!lt.ok) {
      layout.annotations.push({ text: "diverged at " + fmt(lt.t_fail) + " s", xref: "x7", yref: "paper", x: lt.t_fail,
                                y: h, showarrow: false, font: { color: "#D55E00" } });
    }
    Plotly.react(document.getElementById("response"), traces, layout, { displaylogo: false, responsive: true });
  }

  function details(fi, key) {
    var f = fronts[fi], info = memberInfo(fi, key), g = gainTable(f.gain_names, info.gains);
    var h = ["<b>" + esc(info.name) + "</b> &mdash; study " + esc(f.study) + " (" + esc(f.path) + ")",
             "<br>" + objectivesText(info.F, 6)];
    if (!f.traces[key]) { h.push("<br><i>no stored time response for this member (written with --members)</i>"); }
    h.push("<table><tr><th></th>" + doc.dofs.map(function (d) { return "<th>" + d + "</th>"; }).join("") + "</tr>");
    [["CHAT", info.chat], ["RMSE", info.rmse]].forEach(function (r) {
      h.push("<tr><td>" + r[0] + "</td>" + (r[1] || []).map(function (v) { return "<td>" + fmt(v) + "</td>"; }).join("") +
             "</tr>");
    });
    h.push("</table><table><tr><th>gain</th>" + doc.dofs.map(function (d) { return "<th>" + d + "</th>"; }).join("") +
           "</tr>");
    g.order.forEach(function (r) {
      h.push("<tr><td>" + esc(r) + "</td>" + doc.dofs.map(function (d) { return "<td>" + fmt(g.rows[r][d]) + "</td>"; })
        .join("") + "</tr>");
    });
    g.scalars.forEach(function (s) { h.push("<tr><td>" + esc(s[0]) + "</td><td>" + fmt(s[1]) + "</td></tr>"); });
    h.push("</table>");
    if (key !== "defaults") {
      h.push("Replay it: <code>arvcas simulate --from-front " + esc(f.path) + " --index " + esc(key) +
             (f.replay.model_change ? " --allow-model-change" : "") + "</code>");
    }
    h.push(" <button id=\"clear\">clear the selection</button>");
    document.getElementById("details").innerHTML = h.join("");
    document.getElementById("clear").onclick = function () {
      if (selected.length) { selected = [selected[selected.length - 1]]; draw(); }
    };
  }

  frontDiv.on("plotly_click", function (ev) {
    var p = ev.points[0];
    var m = meta[p.curveNumber];
    if (!m || p.customdata === undefined) { return; }
    selectMember(m.front, String(p.customdata), true);
  });

  // ---- the notes and the first selection: every front's knee ----------------------------------------------------
  var notes = fronts.map(function (f) {
    var r = f.replay, what;
    if (r.reproduced) { what = "replays reproduce the stored CHAT and RMSE bit for bit"; }
    else if (f.draws > 1) { what = "objectives over " + f.draws + " draws; time responses of the first"; }
    else { what = "replays differ from the stored metrics by up to " + fmt(r.max_difference, 3) +
                  (r.model_change ? " (" + esc(r.model_change) + ")" : ""); }
    var n = Object.keys(f.traces).length - 1;
    var dflt = f.defaults.F[0] === null ? ", its " + esc(doc.defaults_name) + " diverge on the study's draw" : "";
    return "<b>" + esc(f.label) + "</b>: " + f.F.length + " members, " + n + " with a stored time response, " +
           esc(f.n_gen) + " generations (" + esc(f.status) + "), " + what + dflt;
  });
  var objectives = OBJ.length === 2 && OBJ[0].name === "chat" && OBJ[1].name === "rmse" ?
    "Objectives: mean over the six DOF of CHAT and RMSE, each divided by " + esc(doc.normalisation) +
    ". Diamonds: knees; stars: " :
    "Objectives: " + OBJ.map(function (o) {
      return "f_" + esc(o.name) + (o.unit && o.unit !== "1" ? " (" + esc(o.unit) + ")" : "") +
             (o.description ? ": " + esc(o.description) : "");
    }).join("; ") + "." + (OBJ.length > 2 ? " The plot shows two of the " + OBJ.length + " objectives: a member " +
    "that looks dominated there is better in another." : "") + " Diamonds: knees (pseudo-weights closest to 1/" +
    OBJ.length + " each); stars: ";
  document.getElementById("about").innerHTML = "System " + esc(doc.system) + ". " + objectives +
    esc(doc.defaults_name) + " on the study's draw. " + notes.join("; ") + ". Written by arvcas " +
    esc(doc.arvcas_version) + ".";

  fronts.forEach(function (f, fi) {
    if (f.knee >= 0 && f.traces[String(f.knee)]) { selectMember(fi, String(f.knee), true); }
  });
  if (!selected.length) {
    fronts.some(function (f, fi) {
      var k = Object.keys(f.traces)[0];
      if (k !== undefined) { selectMember(fi, k, true); return true; }
      return false;
    });
  }
  status.textContent = "ready";
  document.body.setAttribute("data-ready", "1");
}());
