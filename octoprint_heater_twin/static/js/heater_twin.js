/*
 * The Heater tuning tab: the server's session state (GET /api/plugin/heater_twin), kept current by the
 * plugin's messages ({state}, {line, sample, cycles_done, progress}, {progress}, {message}); the buttons post
 * start, paste, check (the answer's gains as edited) and apply. The live graph draws M303's readings as SVG.
 */
$(function () {
    var PLUGIN = "heater_twin";
    var CONSOLE_LINES = 400; // as the server keeps (octoprint_heater_twin/session.py)
    var GAIN_DIGITS = 4; // significant digits, as twin-tune writes the gains in the commands it proposes
    var REPORT_INTERVAL_S = 2; // Marlin prints the heaters' states every 2 s during M303 (console.py)
    var GRAPH = {width: 560, temp: 150, gap: 14, power: 46, left: 34, redrawMs: 250}; // the live graph, in px

    function HeaterTwinViewModel(parameters) {
        var self = this;
        self.loginState = parameters[0];
        self.settings = parameters[1];
        self.access = parameters[2];

        self.heater = ko.observable("extruder");
        self.targetC = ko.observable(210);
        self.cycles = ko.observable(8);
        self.pasted = ko.observable("");

        self.phase = ko.observable("idle");
        self.busy = ko.observable(false);
        self.doing = ko.observable("");
        self.error = ko.observable(null);
        self.run = ko.observable(null);
        self.console = ko.observableArray([]);
        self.progress = ko.observable(null);
        self.trace = [];
        self.traceVersion = ko.observable(0); // the trace grows in place: redraws follow this
        self.runTarget = ko.observable(0);
        self.runCycles = ko.observable(0);
        self.cyclesDone = ko.observable(0);
        self.checked = ko.observable(null);
        self.editKp = ko.observable("");
        self.editKi = ko.observable("");
        self.editKd = ko.observable("");
        self.messages = ko.observableArray([]);
        self.answer = ko.observable(null);
        self.applied = ko.observable(null);
        self.noPlot = ko.observable(null);
        self.hasPlot = ko.observable(false);
        self.currentFrom = ko.observable(null);

        self.mayControl = ko.pureComputed(function () {
            return self.loginState.hasPermission(self.access.permissions.CONTROL);
        });
        self.canStart = ko.pureComputed(function () {
            return self.mayControl() && !self.busy();
        });
        self.canPaste = ko.pureComputed(function () {
            return self.canStart() && self.pasted().trim().length > 0;
        });
        self.canApply = ko.pureComputed(function () {
            return self.mayControl() && (self.phase() === "answer" || self.phase() === "applied");
        });
        self.m303 = ko.pureComputed(function () {
            var e = self.heater() === "heater_bed" ? "E-1" : "E0";
            return "M303 " + e + " S" + self.targetC() + " C" + self.cycles();
        });
        self.consoleText = ko.pureComputed(function () {
            return self.console().join("\n");
        });
        self.duration = function (seconds) {
            return seconds < 90 ? seconds + " s" : Math.round(seconds / 60) + " min";
        };
        self.progressText = ko.pureComputed(function () {
            var p = self.progress();
            if (!p) return "";
            var left = p.left_s === null || p.left_s === undefined ? "" :
                ", about " + self.duration(p.left_s) + " left" + (p.left_of ? " of " + p.left_of : "");
            return p.words + " (" + p.percent + "%" + left + ")";
        });
        self.progressPercent = ko.pureComputed(function () {
            var p = self.progress();
            return p ? p.percent : 0;
        });

        // -- the live graph of M303: temperature against its target, and the heater's power, per 2 s report
        self.graph = ko.pureComputed(function () {
            self.traceVersion();
            var trace = self.trace, n = trace.length, target = self.runTarget();
            if (!n) return null;
            var temps = _.map(trace, function (p) { return p[0]; });
            var low = Math.floor(Math.min(_.min(temps), target) / 10) * 10, high = Math.ceil(Math.max(_.max(temps), target) / 10) * 10;
            if (high - low < 10) high = low + 10;
            var span = Math.max(n - 1, 30), w = GRAPH.width - GRAPH.left, top2 = GRAPH.temp + GRAPH.gap;
            var x = function (i) { return (GRAPH.left + (w * i) / span).toFixed(1); };
            var y = function (c) { return ((GRAPH.temp * (high - c)) / (high - low)).toFixed(1); };
            var yp = function (pct) { return (top2 + (GRAPH.power * (100 - pct)) / 100).toFixed(1); };
            var temp = _.map(trace, function (p, i) { return x(i) + "," + y(p[0]); }).join(" ");
            var power = x(0) + "," + yp(0) + " " + _.map(trace, function (p, i) { return x(i) + "," + yp(p[1]); }).join(" ") +
                " " + x(n - 1) + "," + yp(0);
            var last = trace[n - 1];
            return {temp: temp, power: power, targetY: y(target), high: high + " °C", low: low + " °C",
                    end: self.duration(Math.round((span * REPORT_INTERVAL_S))), now: last[0].toFixed(1) + " °C",
                    heater: Math.round(last[1]) + " %", points: n};
        }).extend({rateLimit: GRAPH.redrawMs});
        self.graphSize = GRAPH;
        self.cycleText = ko.pureComputed(function () {
            if (!self.runCycles()) return "";
            return self.cyclesDone() + " of " + self.runCycles() + " cycles done";
        });

        // -- the answer's gains, editable: an edit is checked on the twin before Apply sends it
        self.resetEdits = function () {
            var a = self.answer();
            var g = a && a.answer ? a.answer : null;
            self.editKp(g ? self.gain(g.kp) : "");
            self.editKi(g ? self.gain(g.ki) : "");
            self.editKd(g ? self.gain(g.kd) : "");
        };
        self.editedGains = function () {
            return {kp: Number(self.editKp()), ki: Number(self.editKi()), kd: Number(self.editKd())};
        };
        self.edited = ko.pureComputed(function () {
            var a = self.answer();
            if (!a || !a.answer) return false;
            return self.editKp() !== self.gain(a.answer.kp) || self.editKi() !== self.gain(a.answer.ki) ||
                self.editKd() !== self.gain(a.answer.kd);
        });
        self.checkedEdit = ko.pureComputed(function () {
            var c = self.checked(), g = self.editedGains();
            return c && c.gains.kp === g.kp && c.gains.ki === g.ki && c.gains.kd === g.kd ? c : null;
        });
        self.canCheck = ko.pureComputed(function () {
            return self.canApply() && !self.busy() && self.edited() && !self.checkedEdit();
        });
        self.mayApply = ko.pureComputed(function () {
            if (!self.canApply() || self.busy()) return false;
            return !self.edited() || (self.checkedEdit() !== null && !self.checkedEdit().trips);
        });
        self.commandsText = ko.pureComputed(function () {
            var a = self.answer();
            if (!a) return "";
            if (!self.edited()) return a.commands.join(" ; ");
            var g = self.editedGains(), head = a.heater === "heater_bed" ? "M304" : "M301 E0";
            return head + " P" + g.kp + " I" + g.ki + " D" + g.kd + " ; M500";
        });
        self.consoleOpen = ko.pureComputed(function () {
            return self.phase() === "reading" || self.phase() === "autotune";
        });
        self.plotUrl = ko.pureComputed(function () {
            if (!self.hasPlot() || !self.run()) return null;
            return BASEURL + "api/plugin/" + PLUGIN + "?plot=" + self.run();
        });
        self.tabPlotUrl = ko.pureComputed(function () {
            return self.plotUrl() ? self.plotUrl() + "&figure=tab" : null;
        });

        // per plant, the answer's row (else the best other candidate's: what did not beat yours) and yours
        self.proofRows = ko.pureComputed(function () {
            var a = self.answer();
            if (!a) return [];
            var shown = {};
            return _.filter(a.proof, function (row) {
                var key = row.member + (row.candidate === "yours" ? "/yours" : "/other");
                var pick = row.candidate === "yours" || row.candidate === "answer" || !a.answer;
                if (!pick || shown[key]) return false;
                shown[key] = true;
                return true;
            });
        });

        self.verdictText = function () {
            var a = self.answer();
            if (!a) return "";
            return a.verdict === "new gains" ? "New gains" : "Keep your gains";
        };
        self.gain = function (value) {
            return String(parseFloat(Number(value).toPrecision(GAIN_DIGITS)));
        };
        // a proof row's [mean, worst] to ``decimals`` (as twin-tune's own table: 2 for C, 3 for chatter)
        self.meanWorst = function (pair, decimals) {
            return pair ? pair[0].toFixed(decimals) + " / " + pair[1].toFixed(decimals) : "-";
        };
        self.memberText = function (member) {
            // delta: Akaike units behind the best fit (twin-tune's plants the log allows)
            var delta = member.delta === null || member.delta === undefined ? "" : "(delta " + member.delta.toFixed(1) + ") ";
            return delta + member.replay;
        };

        // a heater's target is the settings' when the heater is chosen
        self.settingsTarget = function (heater) {
            var s = self.settings.settings.plugins.heater_twin;
            return heater === "heater_bed" ? s.bed_target_c() : s.extruder_target_c();
        };
        self.heater.subscribe(function (heater) {
            self.targetC(self.settingsTarget(heater));
        });

        self.fromState = function (state) {
            var newAnswer = state.run !== self.run() || (state.answer && !self.answer());
            self.phase(state.phase);
            self.busy(state.busy);
            self.doing(state.doing || "");
            self.error(state.error);
            self.run(state.run);
            self.console(state.console);
            self.progress(state.progress);
            self.messages(state.messages);
            self.answer(state.answer);
            self.applied(state.applied);
            self.hasPlot(state.plot);
            self.noPlot(state.no_plot);
            self.currentFrom(state.current_from);
            self.checked(state.checked);
            self.trace = state.trace.slice();
            self.runTarget(state.target_c);
            self.runCycles(state.cycles);
            self.cyclesDone(state.cycles_done);
            self.traceVersion(self.traceVersion() + 1);
            if (newAnswer) self.resetEdits();
        };

        self.request = function (command, data) {
            self.error(null);
            OctoPrint.simpleApiCommand(PLUGIN, command, data || {})
                .done(self.fromState)
                .fail(function (xhr) {
                    var reply = xhr.responseJSON || {};
                    self.error(reply.error || xhr.statusText || "The request failed");
                });
        };
        self.start = function () {
            self.request("start", {heater: self.heater(), target_c: self.targetC(), cycles: self.cycles()});
        };
        self.paste = function () {
            self.request("paste", {heater: self.heater(), text: self.pasted()});
        };
        self.check = function () {
            self.request("check", self.editedGains());
        };
        self.apply = function () {
            self.request("apply", self.edited() ? {gains: self.editedGains()} : {});
        };

        self.refresh = function () {
            if (!self.loginState.hasPermission(self.access.permissions.STATUS)) return;
            OctoPrint.simpleApiGet(PLUGIN).done(self.fromState);
        };

        // the tab starts from the settings, and follows them when the settings dialog closes (not during a run)
        self.fromSettings = function () {
            if (self.busy()) return;
            var s = self.settings.settings.plugins.heater_twin;
            self.heater(s.heater());
            self.targetC(self.settingsTarget(self.heater()));
            self.cycles(s.cycles());
        };
        self.onBeforeBinding = self.onSettingsHidden = self.fromSettings;
        self.onStartupComplete = self.onUserLoggedIn = self.refresh;

        self.onDataUpdaterPluginMessage = function (plugin, message) {
            if (plugin !== PLUGIN) return;
            if (message.state) {
                self.fromState(message.state);
            } else if (message.line !== undefined) {
                self.console.push(message.line);
                if (self.console().length > CONSOLE_LINES) self.console.shift();
                var pre = document.getElementById("heater_twin_console");
                if (pre) pre.scrollTop = pre.scrollHeight;
                if (message.sample) {
                    self.trace.push(message.sample);
                    self.traceVersion(self.traceVersion() + 1);
                }
                self.cyclesDone(message.cycles_done);
                self.progress(message.progress);
            } else if (message.progress) {
                self.progress(message.progress);
            } else if (message.message !== undefined) {
                self.messages.push(message.message);
            }
        };
    }

    OCTOPRINT_VIEWMODELS.push({
        construct: HeaterTwinViewModel,
        dependencies: ["loginStateViewModel", "settingsViewModel", "accessViewModel"],
        elements: ["#tab_plugin_heater_twin"]
    });
});
