// The results browser: everything comes from the JSON block above; nothing is fetched.
"use strict";
(function () {
  const D = JSON.parse(document.getElementById("data").textContent);
  const $ = (id) => document.getElementById(id);
  const CATEGORY = { "success-success": "both succeeded", "failure-failure": "both failed", "success-failure": "one succeeded" };

  function el(tag, attrs, ...children) {
    const node = document.createElement(tag);
    for (const [k, v] of Object.entries(attrs || {})) {
      if (v === null || v === undefined || v === false) continue;
      if (k === "class") node.className = v;
      else if (k in node && typeof v !== "string") node[k] = v;
      else node.setAttribute(k, v);
    }
    for (const c of children.flat(Infinity)) if (c !== null && c !== undefined) node.append(c instanceof Node ? c : String(c));
    return node;
  }
  const fmt = (x, d = 1) => (x === null || x === undefined ? "\u2013" : Number(x).toFixed(d));
  const pct = (x, d = 1) => (x === null || x === undefined ? "\u2013" : (100 * x).toFixed(d));
  const ci = (lo, hi, f) => (lo === null || lo === undefined || hi === null || hi === undefined ? "" : ` [${f(lo)}, ${f(hi)}]`);
  const share = (s, noun = "verdicts") => (s && s.share !== null && s.share !== undefined
    ? `${pct(s.share)}%${ci(s.ci_low, s.ci_high, pct)} (${s.n_pairs} ${noun}, ${s.n_units} units)`
    : "\u2013");

  // ------------------------------------------------------------------------ ranking

  function rankingCard(judge, J) {
    const R = J.ranking;
    const rows = R.rows.map((r) => {
      const ref = D.reference[r.policy] || {};
      const bar = el("div", { class: "bar", title: `score ${fmt(r.score)}${ci(r.ci_low, r.ci_high, fmt)}` },
        r.ci_low !== null && r.ci_high !== null ? el("span", { class: "ci", style: `left:${r.ci_low}%;width:${Math.max(0.6, r.ci_high - r.ci_low)}%` }) : null,
        ref.rate !== null && ref.rate !== undefined ? el("span", { class: "ref", style: `left:${100 * ref.rate}%` }) : null,
        el("span", { class: "pt", style: `left:${r.score}%` }));
      return el("tr", {}, el("td", {}, r.policy), el("td", { class: "num" }, `${fmt(r.score)}${ci(r.ci_low, r.ci_high, fmt)}`),
        el("td", {}, bar), el("td", { class: "num" }, `${pct(ref.rate)}${ci(ref.ci_low, ref.ci_high, pct)}`));
    });
    const M = J.metrics;
    const metricRow = (name, key, d) => el("tr", {}, el("td", {}, name),
      ...["last", "average"].map((at) => {
        const m = (M[at] || {})[key] || {};
        return el("td", { class: "num" }, `${fmt(m.value, d)}${ci(m.ci_low, m.ci_high, (x) => fmt(x, d))}`);
      }));
    const C = J.card || {};
    const cardRows = [
      ["Outcome agreement (mixed-outcome pairs)", share(C.outcome_agreement)],
      ["Planted-order agreement (same-outcome pairs)", share(C.planted_order_agreement)],
      ["A share, same-outcome pairs", C.a_share_same_outcome === null || C.a_share_same_outcome === undefined ? "\u2013" : `${pct(C.a_share_same_outcome)}% (${C.n_same_outcome} verdicts)`],
      ["Order-swap consistency", C.swap_consistency === null || C.swap_consistency === undefined ? "\u2013 (not audited)" : `${pct(C.swap_consistency)}% (${C.n_swapped} swapped)`],
      ["Agreement with the human majority", C.human ? share(C.human.judge_agreement) : "\u2013 (no annotations)"],
    ];
    return el("article", { class: "card", "data-judge": judge },
      el("h3", {}, `Judge ${judge}`),
      el("table", { class: "ranking" },
        el("thead", {}, el("tr", {}, el("th", {}, "Policy"), el("th", {}, `BT score [${Math.round(100 * R.ci_level)}% CI]`),
          el("th", {}, "0 \u2013 100"), el("th", {}, "Reference success %"))),
        el("tbody", {}, rows)),
      el("p", { class: "legend" }, el("i"), " score and its interval (", R.interval, " bootstrap), ", el("b"),
        " reference success rate; checkpoint ", String(R.checkpoint), " comparisons per policy pair"),
      el("table", { class: "metrics" },
        el("thead", {}, el("tr", {}, el("th", {}, "vs reference"), el("th", {}, "last checkpoint"), el("th", {}, "average over checkpoints"))),
        el("tbody", {}, metricRow("Spearman \u03c1", "spearman", 3), metricRow("Pearson r", "pearson", 3),
          metricRow("MMRV", "mmrv", 3), metricRow("BT CI width", "ci_width", 2))),
      el("table", { class: "metrics" }, el("tbody", {}, cardRows.map(([k, v]) => el("tr", {}, el("td", {}, k), el("td", { class: "num" }, v))))));
  }

  function renderRanking() {
    const judges = Object.keys(D.judges);
    $("ranking-note").textContent = `${judges.length} judge${judges.length === 1 ? "" : "s"}; reference: ${D.reference_definition || "real success rate"}.`;
    $("judges").append(...judges.map((j) => rankingCard(j, D.judges[j])));
  }

  function renderFigures() {
    $("figure-list").append(...D.figures.map((f) => el("figure", { class: "card" },
      el("a", { href: f.src }, el("img", { src: f.src, alt: f.title, loading: "lazy" })), el("figcaption", {}, f.title))));
  }

  // ---------------------------------------------------------------- human agreement

  function renderHuman() {
    const withHuman = Object.entries(D.judges).filter(([, J]) => J.card && J.card.human);
    if (!withHuman.length) {
      $("human-body").append(el("p", { class: "note" }, "No human annotations in this run (report.judge_audit.human_annotations); see the annotation app: python -m r2s_eval.annotate serve."));
      return;
    }
    const H = withHuman[0][1].card.human;  // the annotators' own agreement is the same in every judge's audit
    const kappa = (f) => (f && f.kappa !== null ? `${fmt(f.kappa, 3)} (${f.n_pairs} pairs \u00d7 ${f.n_raters} raters)` : "\u2013");
    const cats = Object.keys(CATEGORY).filter((c) => c in H.by_category);
    const head = el("tr", {}, el("th", {}, ""), el("th", {}, "all pairs"), ...cats.map((c) => el("th", {}, CATEGORY[c] || c)));
    const part = (block, c) => (c === null ? block : block.by_category[c]);  // c: a category, null for all pairs
    const row = (name, f) => el("tr", {}, el("td", {}, name), ...[null, ...cats].map((c) => el("td", {}, f(c))));
    const rows = [
      row("Pairs annotated", (c) => String(part(H, c).n_pairs)),
      row("Unanimous", (c) => share(part(H, c).unanimous, "pairs")),
      row("Fleiss' \u03ba", (c) => kappa(part(H, c).fleiss)),
      ...withHuman.map(([j, J]) => row(`Judge ${j} agrees with the majority`, (c) => {
        const b = part(J.card.human, c);
        return b ? share(b.judge_agreement) : "\u2013";
      })),
    ];
    $("human-body").append(el("div", { class: "card" },
      el("p", { class: "note" }, `${H.n_annotators} annotators; ${H.n_tied_pairs} tied pairs have no majority.`),
      el("table", { class: "human" }, el("thead", {}, head), el("tbody", {}, rows))));
  }

  // ------------------------------------------------------------- compared rollouts

  const state = { page: 0 };

  function option(value, label) { return el("option", { value }, label); }

  function setupFilters() {
    const pairs = [...new Set(D.pairs.map((p) => `${p.policy_i} vs ${p.policy_j}`))];
    $("f-pair").append(option("", "all"), ...pairs.map((p) => option(p, p)));
    $("f-task").append(option("", "all"), ...D.tasks.map((t) => option(t, t)));
    $("f-outcome").append(option("", "all"), ...Object.entries(CATEGORY).map(([k, v]) => option(k, v)));
    const described = Object.keys(D.descriptions);
    $("f-judge").append(...(described.length ? described.map((j) => option(j, j)) : [option("", "none")]));
    for (const id of ["f-pair", "f-task", "f-outcome", "f-judge", "f-split"]) {
      $(id).addEventListener("change", () => { state.page = 0; renderPairs(); });
    }
    const params = new URLSearchParams(window.location.hash.split("?")[1] || "");
    for (const [key, id] of [["pair", "f-pair"], ["task", "f-task"], ["outcome", "f-outcome"]]) {
      if (params.get(key)) $(id).value = params.get(key);
    }
  }

  function preferred(answers, pair) {
    const forI = answers.filter((a) => a.winner === pair.policy_i).length;
    return { forI, n: answers.length };
  }

  function judgesDisagree(pair) {
    const leaning = Object.values(pair.verdicts).map((answers) => {
      const { forI, n } = preferred(answers, pair);
      return 2 * forI > n ? "i" : 2 * forI < n ? "j" : "tie";
    });
    return new Set(leaning).size > 1;
  }

  function filtered() {
    const pair = $("f-pair").value, task = $("f-task").value, outcome = $("f-outcome").value, split = $("f-split").checked;
    return D.pairs.filter((p) => (!pair || `${p.policy_i} vs ${p.policy_j}` === pair) && (!task || p.task === task)
      && (!outcome || p.category === outcome) && (!split || judgesDisagree(p)));
  }

  function description(judge, episode) {
    const d = (D.descriptions[judge] || {})[episode];
    if (!d) return el("p", { class: "desc muted" }, judge ? `No description by ${judge}.` : "");
    return el("div", { class: "desc" }, el("dl", {}, d.criteria.map(([name, text]) => [el("dt", {}, name), el("dd", {}, text)])),
      el("p", { class: "summary" }, d.summary));
  }

  function video(src, episode) {
    const v = el("video", { src, controls: true, muted: true, playsInline: true, preload: "metadata", "data-episode": episode });
    // Seeking a hair past 0 makes the browser decode and show the first frame instead of black.
    v.addEventListener("loadedmetadata", () => { if (v.currentTime === 0) v.currentTime = 0.001; }, { once: true });
    return v;
  }

  function side(pair, episode, judge) {
    const E = D.episodes[episode];
    return el("div", { class: "side" },
      el("h4", {}, E.policy, el("span", { class: `chip ${E.success ? "ok" : "bad"}` }, E.success ? "success" : "failure"),
        el("span", { class: "muted" }, E.length ? `${E.length} steps` : "")),
      video(E.video, episode),
      description(judge, episode));
  }

  function verdictRows(pair) {
    return Object.entries(pair.verdicts).map(([judge, answers]) => {
      const { forI, n } = preferred(answers, pair);
      const winner = 2 * forI > n ? pair.policy_i : 2 * forI < n ? pair.policy_j : "tie";
      const asA = answers.filter((a) => a.a === pair.policy_i).length;
      const swapped = answers.filter((a) => a.swapped);
      const consistent = swapped.filter((a) => a.swapped !== a.letter).length;
      return el("tr", {}, el("td", {}, judge), el("td", { class: "pref" }, winner),
        el("td", { class: "num" }, `${pair.policy_i} ${forI} : ${n - forI} ${pair.policy_j}`),
        el("td", { class: "num" }, `${pair.policy_i} shown as A in ${asA} of ${n}`),
        el("td", { class: "num" }, swapped.length ? `swapped: ${consistent} of ${swapped.length} consistent (${swapped.map((a) => `${a.letter}\u2192${a.swapped}`).join(", ")})` : "not swapped"));
    });
  }

  function pairCard(pair, judge) {
    const card = el("article", { class: "pair card", "data-category": pair.category, "data-task": pair.task },
      el("header", {}, el("strong", {}, `${pair.policy_i} vs ${pair.policy_j}`), el("span", {}, pair.task),
        el("span", { class: "muted" }, `init ${pair.init_id}`), el("span", { class: "chip" }, CATEGORY[pair.category] || pair.category)),
      el("div", { class: "instruction" }, D.instructions[pair.task] ? `\u201c${D.instructions[pair.task]}\u201d` : ""),
      el("div", { class: "sides" }, side(pair, pair.episode_i, judge), side(pair, pair.episode_j, judge)));
    const videos = () => [...card.querySelectorAll("video")];
    const play = el("button", { type: "button", class: "play-both" }, "\u25b6 play both");
    play.addEventListener("click", () => {
      const vs = videos();
      for (const v of vs) v.currentTime = 0;
      for (const v of vs) v.play();
    });
    const pause = el("button", { type: "button" }, "pause");
    pause.addEventListener("click", () => videos().forEach((v) => v.pause()));
    card.append(el("div", { class: "pair-controls" }, play, pause),
      el("table", { class: "verdicts" }, el("thead", {}, el("tr", {}, el("th", {}, "Judge"), el("th", {}, "Prefers"),
        el("th", {}, "Verdicts"), el("th", {}, "Order"), el("th", {}, "Order swapped"))), el("tbody", {}, verdictRows(pair))));
    return card;
  }

  function renderPairs() {
    const list = filtered();
    const size = D.page_size, pages = Math.max(1, Math.ceil(list.length / size));
    state.page = Math.min(state.page, pages - 1);
    const shown = list.slice(state.page * size, (state.page + 1) * size);
    $("pair-count").textContent = `${list.length} of ${D.pairs.length} distinct rollout pairs`;
    $("pair-list").replaceChildren(...shown.map((p) => pairCard(p, $("f-judge").value)));
    const prev = el("button", { type: "button", disabled: state.page === 0 }, "\u2190 previous");
    const next = el("button", { type: "button", disabled: state.page >= pages - 1 }, "next \u2192");
    prev.addEventListener("click", () => { state.page -= 1; renderPairs(); });
    next.addEventListener("click", () => { state.page += 1; renderPairs(); });
    $("pager").replaceChildren(prev, el("span", { class: "muted" }, `page ${state.page + 1} of ${pages}`), next);
  }

  renderRanking();
  renderFigures();
  renderHuman();
  setupFilters();
  renderPairs();
  document.body.dataset.ready = "true";
})();
